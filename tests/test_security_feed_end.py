"""A live feed whose right is gone stays closed whatever the kit sends meanwhile.

The attack that worked, on a real server: a patient's kit sends ``status`` messages flat
out (any kit may: they are not stored) while a clinic admin moves the patient to another
therapist. The former therapist's ``/ws/live`` feed was ended by putting an end marker
(None) in its queue of updates, and that queue, full, drops its oldest update for each new
one: when the kit's messages reached the hub before the feed's task ran, they pushed the
end marker out, and the feed stayed open for good (the access check does not look at a
feed it closed once), handing the next therapist's patient's live updates to the former
one: 1 reassign in 10, then 1 in 20, under such a flood by hand (0 in 20 with the fix).
Now an ended subscription answers None whatever is published after its end. The race
depends on the event loop's order: the hub test below shows it every time, the real
server's only now and then (it passed 20 of 20 on the unfixed server in one pytest run),
and stays as the end-to-end check that a flood never keeps a former therapist's feed.

The server here reads the kit as fast as it can (its reading budgets lifted, the kit's and
all kits' together), as when the attack was found: under the default budgets
(``ARMTRACK_KIT_MESSAGES_PER_S``, 3000; ``ARMTRACK_INGEST_MESSAGES_PER_S``, 8000) the
flood's status messages, 60 bytes each, wait unread in the kernel's buffers for tens of
seconds, the kit's answers to the server's keepalive pings wait behind them, and after
20 s the server closes the flooding kit (1011, keepalive ping timeout): the right
outcome for such a kit, but it ends the flood this test needs (it failed so in CI)."""

from __future__ import annotations

import asyncio
import json

from armtrack.server.live.hub import QUEUE_SIZE, LiveHub
from server_support import PASSWORD, server_fixture
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

server = server_fixture("feed_end", "alice", "bob",
                        env={"ARMTRACK_KIT_MESSAGES_PER_S": "1e9",
                             "ARMTRACK_KIT_ROWS_PER_S": "1e9",
                             "ARMTRACK_INGEST_MESSAGES_PER_S": "1e9",
                             "ARMTRACK_INGEST_ROWS_PER_S": "1e9"})

TRIALS = 10


def test_an_ended_subscription_stays_ended_whatever_is_published_after():
    async def scenario():
        hub = LiveHub()
        with hub.subscribe(7) as subscription:
            for _ in range(QUEUE_SIZE):
                hub.publish(7, {"kind": "status", "sensor": "forearm"})
            subscription.end()  # the right is gone
            for _ in range(2 * QUEUE_SIZE):  # the kit goes on before the feed's task runs
                hub.publish(7, {"kind": "status", "sensor": "forearm"})
            return await asyncio.wait_for(subscription.get(), 1)

    assert asyncio.run(scenario()) is None


def test_reassigning_under_a_flood_of_status_closes_the_former_therapists_feed(server):
    done = server.armtrack("create-user", "root", "--admin", "--password", PASSWORD)
    assert done.returncode == 0, done.stderr
    root, tokens = server.client("root"), {n: server.client(n).token for n in ("alice", "bob")}
    ids = {t["username"]: t["id"] for t in root.http.get("/api/admin/therapists").json()}
    alice = server.client("alice")
    patient = alice.patient("Moves back and forth")
    kit = alice.device(patient["id"])
    status = json.dumps({"type": "status", "sensor": "forearm", "battery": 0.5})

    async def flood(ws, stop: asyncio.Event) -> None:
        while not stop.is_set():
            await asyncio.gather(*[ws.send(status) for _ in range(200)])
            await asyncio.sleep(0)

    async def scenario() -> list[str]:
        outcomes = []
        kits = [await connect(f"{server.ws_url}?token={kit['token']}") for _ in range(4)]
        for ws in kits:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": ["forearm"],
                                      "rate_hz": 50, "nine_axis": False, "resume": None}))
            assert json.loads(await ws.recv())["type"] == "ready"
        holder = "alice"
        for _ in range(TRIALS):
            other = "bob" if holder == "alice" else "alice"
            feed = await connect(f"ws://127.0.0.1:{server.port}/ws/live?patient="
                                 f"{patient['id']}&token={tokens[holder]}", max_queue=None)
            stop = asyncio.Event()
            floods = [asyncio.create_task(flood(ws, stop)) for ws in kits]
            await asyncio.sleep(0.3)
            answer = await asyncio.to_thread(
                root.http.post, f"/api/admin/patients/{patient['id']}/reassign",
                json={"therapist_id": ids[other]})
            assert answer.status_code == 200, answer.text
            await asyncio.sleep(0.5)
            stop.set()
            await asyncio.gather(*floods)
            try:  # what was sent before the close is read away; then it must close
                async with asyncio.timeout(8):
                    while True:
                        await feed.recv()
            except TimeoutError:
                outcomes.append("open")
                await feed.close()
            except ConnectionClosed as exc:
                outcomes.append(str(exc.rcvd.code if exc.rcvd else None))
            holder = other
        for ws in kits:
            await ws.close()
        return outcomes

    outcomes = asyncio.run(scenario())
    print(f"{TRIALS} reassigns under a status flood, the former therapist's feed: {outcomes}")
    assert outcomes == ["4404"] * TRIALS
