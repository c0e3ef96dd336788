"""A kit remembers its sensors' gyroscope biases on the server (docs/gyro-bias-memory.md),
on a real server process with a real WebSocket kit, on SQLite and PostgreSQL: the second
session of a kit starts from the biases the first one's stillness taught (its live
estimates, its stored ones, and a recording the kit uploads), a session that was never
still leaves the memory as it was, and a removed kit's memory is forgotten (its
replacement starts with none)."""

import asyncio
import io
import json
import threading
import time
from dataclasses import replace

import httpx
import numpy as np
import pytest
from armtrack.estimator.arm import REPORTED_ANGLES
from armtrack.estimator.pipeline import run_recording
from armtrack.estimator.recording import parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate

pytestmark = pytest.mark.both_databases

#: Day 1: a 6-axis kit's elbow and wrist exercise with its N-pose (a rest: each sensor's
#: bias is learnt). Day 2: the same kit (the same draws: the same sensors' biases) on a
#: patient whose trunk sways 8° at 0.15 Hz from the first sample, so nothing is still.
DAY1 = SimulationConfig(exercise="elbow_wrist", seed=0, nine_axis=False)
DAY2 = replace(DAY1, trunk_sway=(8.0, 0.15))


@pytest.fixture(scope="module")
def alice(module_server):
    return module_server.client("alice")


def stream(server, token: str, recording, live=None, hello: dict | None = None) -> int:
    """Stream ``recording`` as a kit does (samples in time order across sensors, the
    calibration marks; ``hello``'s extra fields in its hello), say bye (once the ``live``
    feed, if given, has shown the estimates up to the end: a loaded machine's live
    estimation lags); the session's id."""
    from websockets.asyncio.client import connect

    messages = []
    for name, s in recording.sensors.items():
        rows = [[*row, None, None, None]
                for row in np.column_stack([s.t, s.acc, s.gyr]).tolist()]  # 6-axis
        for start in range(0, len(rows), 50):
            messages.append((rows[start][0], {"type": "samples", "sensor": name,
                                              "rows": rows[start:start + 50]}))
    for pose in recording.calibration:
        messages.append((pose.start, {"type": "mark", "t": pose.start, "label": pose.name}))
        messages.append((pose.end, {"type": "mark", "t": pose.end,
                                    "label": f"end:{pose.name}"}))
    messages.sort(key=lambda m: m[0])

    async def run() -> int:
        async with connect(server.ws_url,
                           additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": list(recording.sensors),
                                      "rate_hz": 100, "nine_axis": False, "resume": None,
                                      **(hello or {})}))
            ready = json.loads(await ws.recv())
            assert ready["type"] == "ready", ready
            for seq, (_, message) in enumerate(messages):
                await ws.send(json.dumps({**message, "seq": seq}))
            while json.loads(await ws.recv()) != {"type": "ack", "seq": len(messages) - 1}:
                pass
            if live is not None:
                end = min(float(s.t[-1]) for s in recording.sensors.values())
                await asyncio.to_thread(live.wait_until, end - 2.0)
            await ws.send(json.dumps({"type": "bye"}))
            return ready["session"]

    return asyncio.run(run())


class LiveFeed:
    """The therapist's live feed of a patient (``/ws/live``), read on a thread: every
    pose's trail of angles (t [s], degrees in ``REPORTED_ANGLES`` order)."""

    def __init__(self, server, api, patient_id: int):
        self.url = (server.url.replace("http", "ws", 1)
                    + f"/ws/live?patient={patient_id}&token={api.token}")
        self.trail_t: list[float] = []
        self.trail_deg: list[list[float]] = []
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._listen()),
                                        daemon=True)

    async def _listen(self) -> None:
        import websockets
        async with websockets.connect(self.url) as socket:
            self._ready.set()
            while not self._stop.is_set():
                try:
                    update = json.loads(await asyncio.wait_for(socket.recv(), 0.5))
                except TimeoutError:
                    continue
                if update.get("kind") == "pose":
                    self.trail_t += update["trail"]["t"]
                    self.trail_deg += update["trail"]["angles_deg"]

    def wait_until(self, t: float, timeout: float = 120.0) -> None:
        """Until the feed has shown an estimate at ``t`` [s] or later, or has shown nothing
        new for 10 s (a pose comes with a batch of the stream: the last batch's may be
        held back by the poses' rate limit)."""
        deadline = time.monotonic() + timeout
        seen, since = 0, time.monotonic()
        while not (self.trail_t and self.trail_t[-1] >= t):
            if len(self.trail_t) != seen:
                seen, since = len(self.trail_t), time.monotonic()
            elif time.monotonic() - since > 10.0:
                return
            assert time.monotonic() < deadline, f"the live feed did not reach {t} s"
            time.sleep(0.1)

    def __enter__(self):
        self._thread.start()
        assert self._ready.wait(30), "the live feed did not open"
        return self

    def __exit__(self, *exc):
        time.sleep(1.0)  # the last poses
        self._stop.set()
        self._thread.join(10)


def true_biases(config):
    sim = simulate(config)
    unbiased = simulate(replace(config, gyro_bias_max=0.0)).recording.sensors
    return sim, {s: np.mean(st.gyr - unbiased[s].gyr, axis=0)
                 for s, st in sim.recording.sensors.items()}


def exported(alice, session_id):
    answer = alice.http.get(f"/api/sessions/{session_id}/recording.csv")
    answer.raise_for_status()
    return parse_recording(answer.content)


def stored_angles(alice, session_id):
    answer = alice.http.get(f"/api/sessions/{session_id}/angles.csv")
    answer.raise_for_status()
    return np.genfromtxt(io.StringIO(answer.text), delimiter=",", names=True)


def prior_of(session) -> dict | None:
    prior = (session["estimator"] or {}).get("gyro_bias_prior")
    return None if prior is None else {s: np.array(v["bias_rad_s"])
                                       for s, v in prior["sensors"].items()}


def test_the_second_session_of_a_kit_starts_from_the_first_ones_biases(module_server, alice):
    server = module_server
    (day1, true1), (day2, _) = true_biases(DAY1), true_biases(DAY2)
    patient = alice.patient("Remembered kit")
    kit = alice.device(patient["id"])

    first = alice.wait_processed(stream(server, kit["token"], day1.recording))
    assert first["processed"] and prior_of(first) is None  # a new kit remembers nothing
    learnt = run_recording(exported(alice, first["id"])).learnt_biases()
    rows = server.sql("SELECT sensor, bias_x, bias_y, bias_z, learnt, session_id FROM "
                      "kit_gyro_biases WHERE device_id = :d ORDER BY sensor", d=kit["id"])
    assert {r[0] for r in rows} == set(day1.recording.sensors)
    for sensor, bx, by, bz, how, session_id in rows:
        error = np.linalg.norm(np.array([bx, by, bz]) - true1[sensor]) * 1e3
        print(f"kit memory after session 1: {sensor} learnt at a {how}, {error:.2f} mrad/s "
              "from the truth")
        assert how == "rest" and session_id == first["id"] and error < 1.0
        np.testing.assert_allclose([bx, by, bz], learnt[sensor].bias, atol=1e-12)

    with LiveFeed(server, alice, patient["id"]) as live:
        second = alice.wait_processed(stream(server, kit["token"], day2.recording, live))
    prior = prior_of(second)
    assert prior is not None and set(prior) == set(day1.recording.sensors)
    for sensor, value in prior.items():
        np.testing.assert_allclose(value, learnt[sensor].bias, atol=1e-12)
    # its stored estimates are the pipeline's from that prior (armtrack estimate
    # --gyro-bias-in), not the cold ones, and they hold against the truth
    recording2 = exported(alice, second["id"])
    warm = run_recording(recording2, gyr_bias_priors=prior).finish()
    cold = run_recording(recording2).finish()
    table = stored_angles(alice, second["id"])
    np.testing.assert_allclose(table["t"], warm.t, atol=1e-6)
    np.testing.assert_allclose(table["forearm_pronation"],
                               np.rad2deg(warm.angles["forearm_pronation"]), atol=1e-3)
    scored = warm.t > 10.5
    arm_angles = ("elbow_flexion", "forearm_pronation", "wrist_flexion", "wrist_deviation")

    def rmse(estimates):
        """RMSE [deg] of each of the arm's angles against session 2's truth, after 10.5 s."""
        return {k: float(np.sqrt(np.mean((np.rad2deg(estimates.angles[k]) - np.interp(
            estimates.t, day2.truth.t, np.rad2deg(day2.truth.angles[k])))[scored] ** 2)))
            for k in arm_angles}
    cold_deg, warm_deg = rmse(cold), rmse(warm)
    print("session 2 (trunk swaying, never still), cold → stored from session 1's biases: "
          + ", ".join(f"{k} {cold_deg[k]:.2f}° → {warm_deg[k]:.2f}°" for k in arm_angles))
    # Cold, the forearm's pronation is held by the elbow too (qcf's tilt windows learn the
    # bias in motion, and since 19bd042 the elbow fits the two sensors' drift apart:
    # 10.77° before the windows, 1.43° before 19bd042, 0.77° now): the memory's help is
    # read over the arm's four angles (test_cli's day 2 is this recording).
    assert max(warm_deg.values()) <= 2.0
    assert np.mean(np.square(list(warm_deg.values()))) < \
        np.mean(np.square(list(cold_deg.values())))
    # … and so do its live estimates: the live pipeline started from the same prior
    pronation = REPORTED_ANGLES.index("forearm_pronation")
    live_t = np.array(live.trail_t)
    live_deg = np.array([row[pronation] for row in live.trail_deg])
    later = live_t > 20.0  # where the cold estimate has drifted apart
    off_warm = np.abs(live_deg - np.interp(live_t, warm.t,
                                          np.rad2deg(warm.angles["forearm_pronation"])))
    off_cold = np.abs(live_deg - np.interp(live_t, cold.t,
                                          np.rad2deg(cold.angles["forearm_pronation"])))
    print(f"live feed: {len(live_t)} trail estimates up to {live_t.max():.1f} s; forearm "
          f"pronation after 20 s within {off_warm[later].max():.3f}° of the stored ones, up "
          f"to {off_cold[later].max():.1f}° from the cold ones")
    assert later.sum() >= 100
    # the live feed is the warm pipeline's (within 0.011°), not the cold one's: the two
    # differ by 1.56° at most here (over 2° before 19bd042's elbow held the cold pronation
    # too), a hundred times the match, so the test still tells them apart
    assert off_warm[later].max() <= 0.011 and off_cold[later].max() > 100 * 0.011
    # session 2 taught nothing: the memory is session 1's still
    after = server.sql("SELECT sensor, session_id FROM kit_gyro_biases WHERE device_id = :d",
                       d=kit["id"])
    assert {r[1] for r in after} == {first["id"]}

    # a recording the kit made offline and uploads with its token starts from it too
    answer = httpx.post(f"{server.url}/api/recordings", timeout=120,
                        headers={"Authorization": f"Bearer {kit['token']}"},
                        files={"file": ("offline.csv", alice.http.get(
                            f"/api/sessions/{second['id']}/recording.csv").content)})
    assert answer.status_code in (200, 201), answer.text
    uploaded = alice.wait_processed(answer.json()["id"])
    assert prior_of(uploaded) is not None
    for sensor, value in prior_of(uploaded).items():
        np.testing.assert_allclose(value, learnt[sensor].bias, atol=1e-12)
    np.testing.assert_allclose(stored_angles(alice, uploaded["id"])["forearm_pronation"],
                               np.rad2deg(warm.angles["forearm_pronation"]), atol=1e-3)

    # the kit is removed and a new one paired: the old memory is forgotten, none carried
    assert alice.http.delete(f"/api/devices/{kit['id']}").status_code == 204
    assert server.sql("SELECT count(*) FROM kit_gyro_biases WHERE device_id = :d",
                      d=kit["id"]) == [(0,)]
    new_kit = alice.device(patient["id"], "new kit")
    third = alice.wait_processed(stream(server, new_kit["token"], day2.recording))
    assert prior_of(third) is None
    np.testing.assert_allclose(stored_angles(alice, third["id"])["forearm_pronation"],
                               np.rad2deg(cold.angles["forearm_pronation"]), atol=1e-3)

