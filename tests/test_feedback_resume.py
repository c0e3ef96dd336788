"""Live repetitions after a reconnect (issue 19): a forearm phone doing 5 elbow flexions
loses its connection between the second and the third and resumes its stream (the same
session). The repetitions a kit shows — by the feedback extension's rule
(``docs/extensions/kit-feedback.md``: the counts of each counting run, ``count_from``,
added up) — must be the 5 it did. Before: the resumed stream's live estimator started
anew without the session's calibration poses, so no estimate (and no count) came for the
rest of the exercise, and the kit showed 2. A real server, a real WebSocket client, the
live estimation process; the phone streams at 2× real time (live poses are counted per
wall second)."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace

import pytest
from armtrack.estimator.arm.joints import REPORTED_ANGLES
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.recording import Mark
from armtrack.estimator.simulation import ImuErrors, SimulationConfig, simulate
from armtrack.server.emulator import MessagePlan, hello_message
from server_support import send_paced, server_fixture
from websockets.asyncio.client import connect

SPEED = 2.0
REPS = 5
CUT_AT_S = 20.5  # recording time: after the second repetition's return


server = server_fixture("resume", "alice")


def _simulation(seed: int = 1, repetitions: int = REPS, exercise: str = "elbow_flexion",
                height_m: float = 1.75):
    """A forearm phone's elbow flexions (``exercise``: what the arm does; ``height_m``: the
    patient's), marked as the elbow flexion exercise from 10.5 s to its end: (the
    simulation, its recording with the marks)."""
    config = SimulationConfig(exercise=exercise, sensors=("forearm",), rate_hz=60.0,
                              nine_axis=False, seed=seed, jitter_s=0.003, height_m=height_m,
                              repetitions=repetitions,
                              errors=ImuErrors(gyro_noise=0.01, acc_noise=0.1),
                              gyro_bias_max=0.02, mount_axial_deg=30.0)
    sim = simulate(config)
    end = float(sim.recording.sensors["forearm"].t[-1]) - 0.5
    marks = (*sim.recording.marks, Mark(10.5, "exercise:elbow_flexion"),
             Mark(end, "end:exercise:elbow_flexion"))
    return sim, replace(sim.recording, marks=tuple(sorted(marks, key=lambda m: m.t)))


def _recording():
    return _simulation()[1]


def kit_count(feedback: list[tuple[int, dict]]) -> int:
    """What a kit shows at the end: per counting run (``count_from``; a server without it
    counts per connection, the extension's first rule) its last count, added up."""
    runs: dict[object, int] = {}
    for connection, message in feedback:
        if message["exercise"] != "elbow_flexion":
            continue
        key = message["count_from"] if "count_from" in message else connection
        runs[key] = max(runs.get(key, 0), message["repetitions"])
    return sum(runs.values())


@pytest.mark.parametrize("outage_s", [0.0, 9.0], ids=["quick-resume", "backlog-9s"])
def test_repetitions_go_on_across_a_resumed_stream(server, outage_s):
    """``outage_s``: recording seconds the link is down while the phone goes on recording;
    the resumed stream sends them at once (a backlog), then streams on in real time."""
    api = server.client("alice")
    patient = api.patient("Resumed phone")
    device = api.device(patient["id"], "phone")
    recording = _recording()
    plan = MessagePlan(recording, rows_per_message=6)
    url = f"{server.ws_url}?token={device['token']}"
    feedback: list[tuple[int, dict]] = []

    async def reader(ws, connection: int):
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "feedback":
                feedback.append((connection, message))

    def paced(ws, first: int, stop_at_s: float | None, now_at_s: float | None = None):
        return send_paced(ws, plan, SPEED, first=first, stop_at_s=stop_at_s,
                          now_at_s=now_at_s, hold_at_s=10.4, until=lambda: bool(feedback))

    async def run():
        hello = {**hello_message(recording, "phone"), "extensions": ["feedback/1"]}
        ws = await connect(url)
        await ws.send(json.dumps(hello))
        ready = json.loads(await ws.recv())
        task = asyncio.create_task(reader(ws, 0))
        await paced(ws, 0, CUT_AT_S)
        ws.transport.abort()  # the network goes: no close frame
        task.cancel()
        await asyncio.sleep(0.3 + outage_s / SPEED)
        async with connect(url) as ws2:
            await ws2.send(json.dumps({**hello, "resume": ready["stream"]}))
            again = json.loads(await ws2.recv())
            assert again["type"] == "ready" and again["session"] == ready["session"]
            task2 = asyncio.create_task(reader(ws2, 1))
            await paced(ws2, again["next_seq"], None, CUT_AT_S + outage_s)
            await asyncio.sleep(1.5)
            await ws2.send(json.dumps({"type": "bye"}))
            await asyncio.wait_for(task2, 30)
        return ready

    ready = asyncio.run(run())
    before = [m for c, m in feedback if c == 0 and m["exercise"] == "elbow_flexion"]
    after = [m for c, m in feedback if c == 1 and m["exercise"] == "elbow_flexion"]
    shown = kit_count(feedback)
    print(f"\noutage {outage_s:g} s; feedback: {len(before)} messages before the cut (count "
          f"{before[-1]['repetitions'] if before else None}), {len(after)} after (count "
          f"{after[-1]['repetitions'] if after else None}); the kit shows {shown} of {REPS}")
    assert before and before[-1]["repetitions"] == 2  # cut after the second
    assert after, "no feedback after the resume"
    assert shown == REPS
    session = api.wait_processed(ready["session"], timeout=120)
    assert session["status"] == "closed"


def test_a_count_runs_from_its_mark_or_from_the_first_estimate_after_a_lost_state():
    """``count_from``: the exercise mark's time for a count that ran since the mark; the
    first estimate's time for one started at a resume that lost the live state (its
    marks read back from the session). A mark sent again is not a new exercise."""
    import numpy as np
    from armtrack.server.ingest.feedback import Band, FeedbackTracker

    bands = {"elbow_flexion": Band("elbow_flexion", 0.0, 120.0)}

    def pose(t0: float, up: bool = True) -> dict:
        """A pose at ``t0 + 5`` s whose trail (20 per second, rows in ``REPORTED_ANGLES``
        order) is one elbow flexion to 100° and back from ``t0`` (``up``), or rest."""
        t = t0 + 0.05 * np.arange(1, 101)
        deg = (50.0 * (1.0 - np.cos(2 * np.pi * np.clip((t - t0 - 0.5) / 4.0, 0, 1)))
               if up else np.zeros_like(t))
        return {"t": float(t[-1]), "angles_deg": {"elbow_flexion": float(deg[-1])},
                "trail": {"t": t.tolist(), "angles_deg": [
                    [d if a == "elbow_flexion" else 0.0 for a in REPORTED_ANGLES]
                    for d in deg.tolist()]}}

    live = FeedbackTracker(bands, ("elbow_flexion",), SegmentLengths.from_height(1.75))
    live.mark(10.5, "exercise:elbow_flexion")
    now = 0.0
    for i in range(2):
        now += 1.0
        message = live.pose(pose(10.0 + 5 * i), now)
    assert (message["repetitions"], message["count_from"]) == (2, 10.5)
    live.mark(10.5, "exercise:elbow_flexion")  # sent again after a resume: no new count
    message = live.pose(pose(20.0), now + 1.0)
    assert (message["repetitions"], message["count_from"]) == (3, 10.5)

    lost = FeedbackTracker(bands, ("elbow_flexion",), SegmentLengths.from_height(1.75))
    lost.mark(10.5, "exercise:elbow_flexion", stored=True)
    message = lost.pose(pose(30.0), 1.0)
    assert (message["repetitions"], message["count_from"]) == (1, 30.05)
    lost.mark(40.0, "end:exercise:elbow_flexion")
    message = lost.pose(pose(36.0, up=False), 2.0)
    assert (message["exercise"], message["count_from"]) == (None, None)


def test_a_straight_arm_raise_is_not_counted_on_the_phone(server):
    """The phone on the forearm shows the elbow exercise; the patient raises the straight
    arm forward 5 times instead (the elbow angle reads 150° each time): the phone counts
    none and is told, per counting run, how many movements were not the elbow's
    (``not_elbow_movements``, ``estimator/metrics/elbow_pivot.py``). Streamed at 4× real
    time, the exercise held until the first feedback. The patient is small (1.2 m): the
    raise turns about the shoulder only 0.33 m from the phone, and the threshold is this
    patient's (``pivot_m`` of the session's body; one 0.34 m for every body counted all
    five)."""
    api = server.client("alice")
    patient = api.patient("Raised the arm", height_m=1.2)
    device = api.device(patient["id"], "phone")
    recording = _simulation(seed=0, exercise="shoulder_flexion", height_m=1.2)[1]
    plan = MessagePlan(recording, rows_per_message=12)
    feedback: list[dict] = []

    async def run():
        async with connect(f"{server.ws_url}?token={device['token']}") as ws:
            await ws.send(json.dumps({**hello_message(recording, "phone"),
                                      "extensions": ["feedback/1"]}))
            json.loads(await ws.recv())

            async def reader():
                async for raw in ws:
                    message = json.loads(raw)
                    if message["type"] == "feedback":
                        feedback.append(message)

            task = asyncio.create_task(reader())
            await send_paced(ws, plan, 4.0, hold_at_s=10.4, until=lambda: bool(feedback))
            await asyncio.sleep(1.5)
            await ws.send(json.dumps({"type": "bye"}))
            await asyncio.wait_for(task, 30)

    asyncio.run(run())
    counted = [m for m in feedback if m["exercise"] == "elbow_flexion"]
    last = counted[-1] if counted else {}
    print(f"\n{len(counted)} feedback messages; the last: repetitions "
          f"{last.get('repetitions')}, not_elbow_movements {last.get('not_elbow_movements')}")
    assert counted and max(m["repetitions"] for m in counted) == 0
    assert last.get("not_elbow_movements") == REPS
