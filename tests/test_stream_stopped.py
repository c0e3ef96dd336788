"""The therapist is told when the server stopped a kit's stream (docs/extensions/
stream-stopped.md): after ``ready`` the server closes a stream 4429 when more than
``ARMTRACK_REFUSED_LIMIT`` of the kit's own messages were refused in a window, and the
phone kit then stops for good and tells the patient to contact the therapist (7692b19).
The session's API answer, the live status, the patient page and the session page say
that the server stopped it, why (the limit and the last refused message) and when.

Real server (a real database file, ``ARMTRACK_REFUSED_LIMIT=2``), a real WebSocket kit,
real headless chromium at 390 and 1366 px."""

from __future__ import annotations

import asyncio
import json
import time
from datetime import UTC, datetime

import pytest
import test_pages_browser
from browser_helpers import sign_in_as
from server_support import ServerProcess
from test_pages_browser import sync_api
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

browser_context = test_pages_browser.browser_context
page = test_pages_browser.page
shots = test_pages_browser.shots

HELLO = {"type": "hello", "protocol": 1, "device": "phone", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}
SLOW_MS = 60_000


@pytest.fixture(scope="module")
def refusing(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("stopped"),
                            env={"ARMTRACK_REFUSED_LIMIT": "2"})
    process.create_user("alice")
    process.create_user("bob")
    process.start()
    yield process
    process.stop()


async def stream_until_stopped(url: str) -> tuple[dict, int, str, list[str]]:
    """Samples (acked), then marks with a 101-character label until the server closes:
    ready, the close code and reason, and the errors' reasons."""
    reasons = []
    async with connect(url, max_size=None) as ws:
        await ws.send(json.dumps(HELLO))
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        seq = ready["next_seq"]
        rows = [[i / 50, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0] for i in range(50)]
        await ws.send(json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                                  "columns": ["t", "ax", "ay", "az", "gx", "gy", "gz"],
                                  "rows": rows}))
        while (message := json.loads(await ws.recv()))["type"] != "ack":
            pass
        try:
            for n in range(1, 10):
                await ws.send(json.dumps({"type": "mark", "seq": seq + n, "t": 0.5,
                                          "label": "x" * 101}))
            async for raw in ws:
                message = json.loads(raw)
                if message["type"] == "error":
                    reasons.append(message["reason"])
        except ConnectionClosed:
            pass
        await ws.wait_closed()
        return ready, ws.close_code, ws.close_reason, reasons


def wait_for(condition, what: str, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if value := condition():
            return value
        time.sleep(0.2)
    raise AssertionError(f"{what} did not happen within {timeout:.0f} s")


@pytest.fixture(scope="module")
def stopped_session(refusing):
    api = refusing.client("alice")
    patient = api.patient("Stopped Patient")
    kit = api.device(patient["id"], "phone")
    before = datetime.now(UTC)
    ready, code, reason, refused = asyncio.run(
        stream_until_stopped(f"{refusing.ws_url}?token={kit['token']}"))
    after = datetime.now(UTC)
    print(f"\nclosed {code} {reason!r} after {len(refused)} refused: {refused[-1][:80]!r}")
    assert code == 4429 and "refused messages" in reason
    session = wait_for(lambda: (s := api.session(ready["session"]))["status"] == "interrupted"
                       and s, "the stopped stream's session marked interrupted")
    return api, patient, session, before, after


def test_the_sessions_answer_says_the_server_stopped_the_stream_why_and_when(
        refusing, stopped_session):
    api, patient, session, before, after = stopped_session
    stopped = session.get("stopped_by_server")
    print(f"stopped_by_server: {stopped}")
    assert stopped is not None, sorted(session)
    assert stopped["close_code"] == 4429
    at = datetime.fromisoformat(stopped["at"])
    assert before <= at <= after, (before, at, after)
    assert stopped["refused"] == 3 and stopped["refused_limit"] == 2
    assert "label" in stopped["last_refused"] and "100" in stopped["last_refused"]
    # in words a therapist acts on: who stopped it, why, that the patient was told, what next
    words = stopped["message"]
    for part in ("server stopped", "refused", "contact you", "Close"):
        assert part in words, words
    # the same in the patient's list and in the live status
    listed = {s["id"]: s for s in api.http.get(
        f"/api/patients/{patient['id']}/sessions").json()}
    assert listed[session["id"]]["stopped_by_server"] == stopped
    live = api.http.get(f"/api/patients/{patient['id']}/live").json()
    assert live["session"]["id"] == session["id"]
    assert live["session"]["stopped_by_server"] == stopped
    # another therapist sees nothing of it
    bob = refusing.client("bob")
    assert bob.http.get(f"/api/sessions/{session['id']}").status_code == 404


def test_the_kits_own_text_stays_out_of_the_servers_words(refusing):
    """A refusal's reason quotes the kit's values (an unknown message type, verbatim):
    ``last_refused`` keeps it, shown apart as the kit's, but the server's own words to the
    therapist (``message``) do not carry it: a kit cannot speak in the server's voice
    (before, "… the last one: “unknown message type 'URGENT: … call 555-0100 …'”" stood
    inside the server's sentence)."""
    api = refusing.client("alice")
    patient = api.patient("Loud Kit")
    kit = api.device(patient["id"], "phone")
    words = "URGENT: the patient fell, call 555-0100 before closing this session"

    async def loud():
        async with connect(f"{refusing.ws_url}?token={kit['token']}") as ws:
            await ws.send(json.dumps(HELLO))
            ready = json.loads(await ws.recv())
            try:
                for n in range(5):
                    await ws.send(json.dumps({"type": words, "seq": ready["next_seq"] + n}))
                async for _ in ws:
                    pass
            except ConnectionClosed:
                pass
            return ready, ws.close_code
    ready, code = asyncio.run(loud())
    assert code == 4429
    stop = wait_for(lambda: api.session(ready["session"])["stopped_by_server"],
                    "the stop kept on the session")
    print(f"message: {stop['message']}\nlast_refused: {stop['last_refused']}")
    assert words in stop["last_refused"]
    assert "555-0100" not in stop["message"] and "URGENT" not in stop["message"]
    for part in ("server stopped", "refused", "contact you", "Close"):
        assert part in stop["message"], stop["message"]


def test_a_session_stopped_by_nothing_says_null(refusing):
    api = refusing.client("alice")
    patient = api.patient("Plain Patient")
    kit = api.device(patient["id"], "phone")

    async def plain():
        async with connect(f"{refusing.ws_url}?token={kit['token']}") as ws:
            await ws.send(json.dumps(HELLO))
            ready = json.loads(await ws.recv())
            await ws.send(json.dumps({"type": "bye"}))
            async for _ in ws:
                pass
            return ready
    ready = asyncio.run(plain())
    assert api.session(ready["session"])["stopped_by_server"] is None


@pytest.mark.slow
def test_the_patient_and_session_pages_say_the_stream_was_stopped(
        refusing, stopped_session, page, shots):
    _, patient, session, _, _ = stopped_session
    stopped = session["stopped_by_server"]
    sign_in_as(page, refusing.url, "alice")
    for width in (390, 1366):
        page.set_viewport_size({"width": width, "height": 900})
        page.goto(f"{refusing.url}/patients/{patient['id']}")
        live_box = page.locator("#live .stopped-by-server")
        sync_api.expect(live_box).to_contain_text("server stopped", timeout=SLOW_MS)
        card = page.locator(f'#interrupted-card [data-session="{session["id"]}"]')
        sync_api.expect(card).to_contain_text("stopped by the server", timeout=SLOW_MS)
        page.screenshot(path=str(shots / f"stopped-patient-{width}.png"), full_page=True)
        text = live_box.inner_text()
        print(f"patient page at {width}: {text!r}")
        assert "too many" in text and "contact you" in text
        wide = page.evaluate("document.documentElement.scrollWidth")
        assert wide <= width, f"patient page {wide} px wide at {width}"

        page.goto(f"{refusing.url}/sessions/{session['id']}")
        note = page.locator("#stopped-by-server")
        sync_api.expect(note).to_contain_text("server stopped", timeout=SLOW_MS)
        page.screenshot(path=str(shots / f"stopped-session-{width}.png"), full_page=True)
        text = note.inner_text()
        print(f"session page at {width}: {text!r}")
        assert stopped["last_refused"][:40] in text  # why, the server's own words
        assert "contact you" in text
        wide = page.evaluate("document.documentElement.scrollWidth")
        assert wide <= width, f"session page {wide} px wide at {width}"
