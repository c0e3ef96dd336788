"""Security review (Low): one therapist's sign-in — or a stolen token — opened live feeds
(``/ws/live``), 3D views and viewer grants without bound, each a subscription, a socket
and for a view a viser scene. One account holds at most ``ARMTRACK_MAX_LIVE_FEEDS_PER_USER``
of them at once (live feeds, open 3D views and viewer grants not yet used, together); the
next is refused naming the setting, and a feed that ends gives its place back at once
(a closed tab, a dropped connection), an unused grant when it expires."""

from __future__ import annotations

import asyncio
import time

import pytest
from server_support import ServerProcess
from test_security_feeds import close_code, open_live, open_viewer, still_open
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

LIMIT = 4
GRANT_S = 3.0
SETTING = "ARMTRACK_MAX_LIVE_FEEDS_PER_USER"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("feed_cap"), env={
        SETTING: str(LIMIT), "ARMTRACK_VIEWER_GRANT_S": str(GRANT_S)})
    for user in ("alice", "bob"):
        process.create_user(user)
    process.start()
    yield process
    process.stop()


async def refused_live(server, token: str, patient_id: int) -> tuple[int, str, list[str]]:
    """A /ws/live over the limit: its close code, close reason and the messages before."""
    ws = await connect(f"ws://127.0.0.1:{server.port}/ws/live?patient={patient_id}",
                       additional_headers={"Authorization": f"Bearer {token}"})
    messages = []
    try:
        async with asyncio.timeout(5):
            while True:
                messages.append(await ws.recv())
    except ConnectionClosed as exc:
        assert exc.rcvd is not None
        return exc.rcvd.code, exc.rcvd.reason, messages
    except TimeoutError:
        await ws.close()
        pytest.fail(f"a live feed over {SETTING} = {LIMIT} stayed open")


async def opens_again(server, token: str, patient_id: int, within_s: float):
    """A /ws/live that opens within ``within_s`` (retried as a page does); the time taken."""
    started = time.monotonic()
    while True:
        ws = await connect(f"ws://127.0.0.1:{server.port}/ws/live?patient={patient_id}",
                           additional_headers={"Authorization": f"Bearer {token}"})
        if await close_code(ws, 0.5) is None:  # stayed open (close_code closed it)
            return time.monotonic() - started
        assert time.monotonic() - started < within_s, \
            f"the slot was not given back within {within_s} s"
        await asyncio.sleep(0.2)


def test_one_account_holds_at_most_the_limit_of_live_feeds_and_views(server):
    alice, alice_again, bob = (server.client("alice"), server.client("alice"),
                               server.client("bob"))
    patient = alice.patient("Ada")
    bobs = bob.patient("Bo")

    async def scenario():
        feeds = [await open_live(server, alice.token, patient["id"]) for _ in range(LIMIT - 1)]
        view = await open_viewer(server, alice, patient["id"])
        # over the limit: a feed, from this sign-in or another of the same account
        for token in (alice.token, alice_again.token):
            code, reason, messages = await refused_live(server, token, patient["id"])
            print("refused feed:", code, reason, messages)
            assert code == 4429 and SETTING in reason, (code, reason)
            assert any(SETTING in m and f"{LIMIT}" in m for m in messages), messages
        grant = await asyncio.to_thread(alice.http.post, "/api/viewer",
                                        json={"patient_id": patient["id"]})
        print("refused grant:", grant.status_code, grant.text)
        assert grant.status_code == 429 and SETTING in grant.json()["detail"], grant.text
        # another therapist is not concerned
        bob_feed = await open_live(server, bob.token, bobs["id"])
        await still_open(bob_feed)
        await still_open(feeds[0])  # the open ones go on
        # a closed tab gives its place back at once
        await feeds.pop().close()
        took = await opens_again(server, alice.token, patient["id"], 3)
        print(f"after a clean close: a new feed in {took:.2f} s")
        # so does a connection dropped without a close handshake
        feeds.pop().transport.abort()
        took = await opens_again(server, alice.token, patient["id"], 5)
        print(f"after a dropped connection: a new feed in {took:.2f} s")
        # and a closed 3D view
        await view.close()
        deadline = time.monotonic() + 5
        while (answer := await asyncio.to_thread(
                alice.http.post, "/api/viewer",
                json={"patient_id": patient["id"]})).status_code == 429:
            assert time.monotonic() < deadline, "the closed view's place was not given back"
            await asyncio.sleep(0.2)
        assert answer.status_code == 200, answer.text
        for ws in (*feeds, bob_feed):
            await ws.close()

    asyncio.run(scenario())


def test_unused_viewer_grants_count_until_they_expire(server):
    carol = "carol"
    server.create_user(carol)
    api = server.client(carol)
    patient = api.patient("Cy")
    answers = [api.http.post("/api/viewer", json={"patient_id": patient["id"]})
               for _ in range(LIMIT + 1)]
    codes = [a.status_code for a in answers]
    print("grants asked one after another:", codes)
    assert codes == [200] * LIMIT + [429], codes
    assert SETTING in answers[-1].json()["detail"]

    async def live_refused():
        return (await refused_live(server, api.token, patient["id"]))[0]

    assert asyncio.run(live_refused()) == 4429  # grants and feeds count together
    time.sleep(GRANT_S + 0.5)  # unused, they expire and give their places back
    after = api.http.post("/api/viewer", json={"patient_id": patient["id"]})
    assert after.status_code == 200, after.text
