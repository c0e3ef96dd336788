"""A lost connection's live side (calibrated estimator, repetition counts) is kept for the
kit's resume, at most 64 at once (``server/services.py``, issue 19). One kit token — any
patient's phone — must not push every other patient's kept live side out by opening and
dropping streams of its own: a kit keeps at most ``ARMTRACK_MAX_STREAMS_PER_KIT`` of them.
Before, a foreign kit that dropped 64 streams while Ada's phone was cut made Ada's resumed
stream start without its calibration: no estimate and no count for the rest of the
exercise. Nor may one therapist's many kits (``KITS`` kits each dropping the most
streams a kit may keep) fill the 64 and push out another therapist's patient: the bound is
shared fairly, the oldest of the biggest holder going first. A real server, real
WebSocket clients, the live estimation process."""

from __future__ import annotations

import asyncio
import json

from armtrack.server.emulator import MessagePlan, hello_message
from server_support import send_paced, server_fixture
from test_feedback_resume import CUT_AT_S, REPS, SPEED, _recording, kit_count
from websockets.asyncio.client import connect

FLOOD = 64  # as many as the server keeps
KITS = 16  # × ARMTRACK_MAX_STREAMS_PER_KIT (4) = 64


server = server_fixture("park", "alice", "mallory")


def test_a_foreign_kit_dropping_streams_does_not_evict_a_patients_live_side(server):
    mallory = server.client("mallory")
    other = mallory.device(mallory.patient("Mallory's own")["id"], "kit")
    _ada_resumes_after_a_flood(server, "Ada", [other["token"]] * FLOOD)


def test_one_therapists_many_kits_do_not_evict_another_therapists_live_side(server):
    mallory = server.client("mallory")
    tokens = [mallory.device(mallory.patient(f"Mallory's {i}")["id"], "kit")["token"]
              for i in range(KITS)]
    per_kit = FLOOD // KITS
    _ada_resumes_after_a_flood(server, "Ada B", [t for t in tokens for _ in range(per_kit)])


def _ada_resumes_after_a_flood(server, name: str, flood_tokens: list[str]) -> None:
    """Ada's phone (alice's patient) is cut mid-exercise; kits of ``flood_tokens`` (one
    stream each) open streams and drop them; Ada's phone resumes: its count goes on."""
    alice = server.client("alice")
    ada = alice.patient(name)
    phone = alice.device(ada["id"], "phone")
    recording = _recording()
    plan = MessagePlan(recording, rows_per_message=6)
    url = f"{server.ws_url}?token={phone['token']}"
    feedback: list[tuple[int, dict]] = []

    async def reader(ws, connection: int):
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "feedback":
                feedback.append((connection, message))

    def paced(ws, first: int, stop_at_s: float | None):
        return send_paced(ws, plan, SPEED, first=first, stop_at_s=stop_at_s, hold_at_s=10.4,
                          until=lambda: bool(feedback))

    async def flood() -> int:
        """The foreign kit opens streams and drops them (no bye): each leaves a live side."""
        hello = hello_message(recording, "kit")
        opened = 0
        for token in flood_tokens:
            async with connect(f"{server.ws_url}?token={token}") as ws:
                await ws.send(json.dumps(hello))
                if json.loads(await ws.recv())["type"] == "ready":
                    opened += 1
            await asyncio.sleep(0.02)  # its socket's end is seen before the next
        return opened

    async def run():
        hello = {**hello_message(recording, "phone"), "extensions": ["feedback/1"]}
        ws = await connect(url)
        await ws.send(json.dumps(hello))
        ready = json.loads(await ws.recv())
        task = asyncio.create_task(reader(ws, 0))
        await paced(ws, 0, CUT_AT_S)
        ws.transport.abort()  # Ada's network goes
        task.cancel()
        opened = await flood()
        async with connect(url) as ws2:
            await ws2.send(json.dumps({**hello, "resume": ready["stream"]}))
            again = json.loads(await ws2.recv())
            assert again["type"] == "ready" and again["session"] == ready["session"]
            task2 = asyncio.create_task(reader(ws2, 1))
            await paced(ws2, again["next_seq"], None)
            await asyncio.sleep(1.5)
            await ws2.send(json.dumps({"type": "bye"}))
            await asyncio.wait_for(task2, 30)
        return opened

    opened = asyncio.run(run())
    after = [m for c, m in feedback if c == 1 and m["exercise"] == "elbow_flexion"]
    shown = kit_count(feedback)
    print(f"\nforeign kits opened and dropped {opened} streams; after the resume "
          f"{len(after)} feedback messages; the kit shows {shown} of {REPS}")
    assert opened == len(flood_tokens)
    assert after, "no feedback after the resume: Ada's live side was pushed out"
    assert shown == REPS
