"""The phone says bye once (found by the CI-identical run of this session, on a busy
machine): test_a_lent_phone_sends_the_last_patients_readings_with_their_own_link found
the last patient's kit token back on the phone after their readings were sent and the
phone cleared. Two acks answered at once each ended in ``_byeWhenDone``; the second, run
after the first had said bye and the page had cleared the phone's storage, said bye again
and saved the session's state (with its token) once more. A session that has said bye
says nothing and saves nothing more. The page's own KitStream in chromium at 390 px, on a
real server; its socket a recorder, since two acks landing between a bye and the clear
cannot be timed from outside."""

from __future__ import annotations

from browser_helpers import need_browser, page_at
from server_support import server_fixture

sync_api = need_browser()

server = server_fixture("bye-once-server", "alice")

TWICE = """async () => {
  const stream = new KitStream({ token: "dev_a", sensor: "forearm", side: "right",
                                 device: "phone" });
  stream.state = { finished: false, ended: true, ratings: [], token: "dev_a" };
  stream.ended = true;
  stream.connected = true;
  const sent = [];
  stream.ws = { readyState: 1, send: (text) => sent.push(JSON.parse(text).type) };
  stream._byeWhenDone();        // the first ack: everything is stored, bye
  await stream._saving;
  await KitStore.clear();       // the page clears the phone (sendAndEnd's done)
  stream._byeWhenDone();        // the second ack, answered after
  await stream._saving;
  return { sent, kept: await KitStore.getState("stream") };
}"""


def test_a_session_says_bye_once_and_saves_nothing_after(server):
    with page_at(390) as page:
        page.goto(f"{server.url}/kit")
        page.wait_for_function("typeof KitStream === 'function' && typeof KitStore === 'object'")
        said = page.evaluate(TWICE)
    print(f"\nsent {said['sent']}, kept after the clear: {said['kept']}")
    assert said["sent"] == ["bye"]
    assert said["kept"] is None, "the session's state (and its token) was saved again"
