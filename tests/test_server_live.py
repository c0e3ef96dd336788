"""The live side of the server: a therapist's feed of a streaming patient (poses, running
range of motion, latency), its access rules, and a kit whose sensor never starts."""

import asyncio
import json
import time

import numpy as np
import pytest
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed


@pytest.fixture(scope="module")
def elbow():
    return simulate(SimulationConfig(exercise="elbow_flexion", repetitions=3, seed=4))


async def watch(server, token, patient_id, until, timeout=60.0, subscribed=None):
    """Live updates of a patient until ``until(updates)`` holds. ``subscribed`` (an
    ``asyncio.Event``) is set once the feed is open: the server subscribes the feed to
    the patient's updates in the same turn of its loop that answers the handshake
    (``live.endpoint``: ``accept`` then ``hub.subscribe``, no wait between), so every
    update published after that reaches it."""
    url = f"ws://127.0.0.1:{server.port}/ws/live?patient={patient_id}"
    updates = []
    async with connect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
        if subscribed is not None:
            subscribed.set()
        async with asyncio.timeout(timeout):
            while not until(updates):
                updates.append(json.loads(await ws.recv()))
    return updates


async def subscribed_or_failed(subscribed: asyncio.Event, watcher: asyncio.Task) -> None:
    """Wait until the watcher's feed is open (``subscribed``), or raise the watcher's
    failure (a refused feed)."""
    opened = asyncio.create_task(subscribed.wait())
    await asyncio.wait({opened, watcher}, timeout=60, return_when=asyncio.FIRST_COMPLETED)
    opened.cancel()
    if not subscribed.is_set():
        if watcher.done():
            watcher.result()  # its error
        raise AssertionError("the live feed did not open in 60 s")


def stream_while_watching(server, api, patient_id, token, recording, until, speed=4.0):
    """A kit streams ``recording`` while the therapist watches the patient's feed until
    ``until(updates)``: (the kit's stats, the updates)."""
    async def scenario():
        subscribed = asyncio.Event()
        watcher = asyncio.create_task(watch(server, api.token, patient_id, until,
                                            subscribed=subscribed))
        await subscribed_or_failed(subscribed, watcher)
        stats = await KitEmulator(recording, server.ws_url, token, speed=speed).run()
        return stats, await watcher

    return asyncio.run(scenario())


def test_a_therapist_watches_poses_and_range_of_motion_live(module_server, elbow):
    api = module_server.client("alice")
    patient = api.patient()
    token = api.device(patient["id"])["token"]
    stats, updates = stream_while_watching(
        module_server, api, patient["id"], token, elbow.recording,
        lambda ups: any(u["kind"] == "session" and u["status"] == "closed" for u in ups))
    assert stats.acked == stats.total
    poses = [u for u in updates if u["kind"] == "pose"]
    assert len(poses) > 20
    last = poses[-1]
    assert set(last["angles_deg"]) >= {"elbow_flexion", "shoulder_flexion"}
    assert set(last["segments_q"]) == {"thorax", "clavicle", "upper_arm", "forearm", "hand"}
    latencies = np.array([p["latency_s"] for p in poses])
    print(f"{len(poses)} poses, latency p50 {1000 * np.median(latencies):.1f} ms, "
          f"p99 {1000 * np.quantile(latencies, 0.99):.1f} ms")
    assert np.quantile(latencies, 0.99) < 0.1
    # the running range of motion of the elbow, against the truth after calibration
    truth = np.rad2deg(elbow.truth.angles["elbow_flexion"])
    after = elbow.truth.t >= max(p.end for p in elbow.recording.calibration) + 2.5
    rom = last["rom_deg"]["elbow_flexion"]
    print(f"elbow live range {rom['min']:.1f}…{rom['max']:.1f}°, truth "
          f"{truth[after].min():.1f}…{truth[after].max():.1f}°")
    assert abs(rom["max"] - truth[after].max()) < 2.0
    assert abs(rom["min"] - truth[after].min()) < 2.0


def test_the_feed_refuses_no_token_and_other_therapists_patients(module_server):
    alice, bob = module_server.client("alice"), module_server.client("bob")
    patient = alice.patient()

    async def close_code(headers):
        url = f"ws://127.0.0.1:{module_server.port}/ws/live?patient={patient['id']}"
        async with connect(url, additional_headers=headers) as ws:
            with pytest.raises(ConnectionClosed) as closed:
                await ws.recv()
        return closed.value.rcvd.code

    assert asyncio.run(close_code({})) == 4401
    assert asyncio.run(close_code({"Authorization": "Bearer nonsense"})) == 4401
    assert asyncio.run(close_code({"Authorization": f"Bearer {bob.token}"})) == 4404


def test_a_sensor_that_never_starts_does_not_stop_the_live_view(module_server, elbow):
    api = module_server.client("alice")
    patient = api.patient()
    token = api.device(patient["id"])["token"]
    recording = elbow.recording

    async def scenario():
        def posed(ups):
            return any(u["kind"] == "pose" for u in ups)
        subscribed = asyncio.Event()
        watcher = asyncio.create_task(watch(module_server, api.token, patient["id"], posed,
                                            subscribed=subscribed))
        await subscribed_or_failed(subscribed, watcher)
        async with connect(module_server.ws_url,
                           additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": ["upper_arm", "forearm",
                                                                   "hand"],
                                      "rate_hz": 100, "nine_axis": True, "resume": None}))
            assert json.loads(await ws.recv())["type"] == "ready"
            seq = 0
            for pose in recording.calibration:
                for t, label in ((pose.start, pose.name), (pose.end, f"end:{pose.name}")):
                    await ws.send(json.dumps({"type": "mark", "seq": seq, "t": t,
                                              "label": label}))
                    seq += 1
            for start in range(0, 1500, 10):  # 15 s of two sensors; the hand is silent
                for name in ("upper_arm", "forearm"):
                    s = recording.sensors[name]
                    rows = np.column_stack([s.t, s.acc, s.gyr, s.mag])[start:start + 10]
                    await ws.send(json.dumps({"type": "samples", "seq": seq, "sensor": name,
                                              "rows": rows.tolist()}))
                    seq += 1
            return await watcher

    updates = asyncio.run(scenario())
    pose = next(u for u in updates if u["kind"] == "pose")
    assert any("sensor hand sent nothing" in w for w in pose["warnings"])


def _live_estimation_processes(server) -> list[int]:
    """The server's live estimation processes (its children started by multiprocessing
    that named themselves so; the processing process is another)."""
    from pathlib import Path

    from armtrack.server.processes import LIVE_ESTIMATION

    pids = []
    for task in Path(f"/proc/{server.process.pid}/task").iterdir():
        pids += [int(p) for p in (task / "children").read_text().split()]
    return [p for p in pids
            if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()
            and Path(f"/proc/{p}/comm").read_text().strip() == LIVE_ESTIMATION]


def test_the_live_view_says_so_when_its_estimation_process_dies_and_data_go_on(
        module_server, elbow):
    """The live estimation process killed mid-stream: the therapist's feed gets an error
    naming it, the stream is stored whole, and the next stream has live poses again."""
    import os
    import signal

    api = module_server.client("alice")
    patient = api.patient()
    token = api.device(patient["id"])["token"]
    killed = []

    def kill_at_first_pose_until_an_error(ups):
        if any(u["kind"] == "pose" for u in ups) and not killed:
            children = _live_estimation_processes(module_server)
            assert children, "no live estimation process found"
            for pid in children:
                os.kill(pid, signal.SIGKILL)
            killed.extend(children)
        return any(u["kind"] == "error" for u in ups)

    stats, updates = stream_while_watching(module_server, api, patient["id"], token,
                                           elbow.recording, kill_at_first_pose_until_an_error,
                                           speed=3)
    error = next(u for u in updates if u["kind"] == "error")
    print(f"killed {killed}; the feed said: {error['reason']}")
    assert "live estimation process stopped" in error["reason"]
    assert stats.acked == stats.total  # the stream went on, every message stored
    session = api.wait_processed(error["session_id"])
    assert session["samples"] == sum(len(s.t) for s in elbow.recording.sensors.values())

    # a new stream: a new live estimation process, poses again
    _, updates = stream_while_watching(module_server, api, patient["id"], token,
                                       elbow.recording,
                                       lambda ups: any(u["kind"] == "pose" for u in ups),
                                       speed=3)
    assert any(u["kind"] == "pose" for u in updates)
    assert set(_live_estimation_processes(module_server)).isdisjoint(killed)


def test_live_estimates_on_threads_of_the_server_process_when_asked(tmp_path, elbow):
    """``ARMTRACK_LIVE_PROCESSES=0``: no live estimation process; the estimators run on
    the server's own threads, and the feed has poses all the same."""
    from server_support import ServerProcess

    server = ServerProcess(tmp_path / "server", {"ARMTRACK_LIVE_PROCESSES": "0"})
    server.create_user("alice")
    server.start()
    try:
        api = server.client("alice")
        patient = api.patient()
        token = api.device(patient["id"])["token"]

        stats, updates = stream_while_watching(
            server, api, patient["id"], token, elbow.recording,
            lambda ups: sum(u["kind"] == "pose" for u in ups) >= 10)
        assert stats.acked == stats.total
        assert sum(u["kind"] == "pose" for u in updates) >= 10
        assert _live_estimation_processes(server) == []
    finally:
        server.stop()


def test_the_running_range_of_motion_agrees_with_the_array_reference():
    """The compiled one-pass range update widens min/max exactly as the array version
    did (NumPy's rad2deg of the chunk, fmin/fmax; a chunk with a NaN in an angle
    changes nothing of it; only times ≥ start_s count), on 5,000 random chunks."""
    from armtrack.estimator.arm.joints import REPORTED_ANGLES
    from armtrack.server.live.estimator import RunningRange

    k = len(REPORTED_ANGLES)
    rng = np.random.default_rng(1)
    changed = 0
    for _ in range(5000):
        n = int(rng.integers(1, 12))
        t = np.sort(rng.uniform(0, 10, n))
        radians = rng.normal(0, 2, (k, n))
        if rng.random() < 0.3:
            radians[rng.integers(k), rng.integers(n)] = np.nan
        rom = RunningRange()
        rom.start_s = rng.uniform(-1, 11)
        if rng.random() < 0.7:
            rom.low[:] = rng.normal(0, 50, k)
            rom.high[:] = rom.low + 30
        low, high = rom.low.copy(), rom.high.copy()
        rom.update(t, radians.T.copy())  # (n, angles), as the pipeline's kernel gives them
        keep = t >= rom.start_s
        if keep.any():
            degrees = np.rad2deg(radians)[:, keep]
            low, high = np.fmin(low, degrees.min(axis=1)), np.fmax(high, degrees.max(axis=1))
        assert np.array_equal(rom.low, low) and np.array_equal(rom.high, high)
        changed += rom._as_dict is None
    assert changed > 1000  # the cases did widen the range, often


def test_an_encoded_pose_is_the_json_of_its_dict_and_reads_as_it():
    """The live estimation process encodes each pose once: the text viewers get is, byte
    for byte, the JSON of the dict with ``latency_s`` appended last (as the server added
    it before); it reads as that dict, and pickles as its text alone."""
    import pickle

    import orjson
    from armtrack.server.live.encoded import EncodedPose

    pose = {"kind": "pose", "session_id": 7, "t": 12.5,
            "angles_deg": {"elbow_flexion": 91.25, "wrist_flexion": -3.5e-7},
            "positions_m": {"wrist": [0.1, -0.2, 0.30000000000000004]},
            "rom_deg": {}, "estimates": 1250, "warnings": ["sensor hand sent nothing"]}
    encoded = EncodedPose.encode(pose).with_field("latency_s", 0.012345678901234)
    as_dict = {**pose, "latency_s": 0.012345678901234}
    assert encoded.text == orjson.dumps(as_dict)
    assert dict(encoded) == as_dict and encoded["angles_deg"]["elbow_flexion"] == 91.25
    assert encoded.get("kind") == "pose" and encoded.warnings == ("sensor hand sent nothing",)
    copy = pickle.loads(pickle.dumps(encoded, pickle.HIGHEST_PROTOCOL))
    assert copy.text == encoded.text and copy._parsed is None
    assert copy.warnings == encoded.warnings


def test_a_pose_cut_off_by_a_lost_stream_is_not_reported_as_held(module_server, elbow):
    """Left by the live page's fix (test_last_seen_browser): a kit cut off in the middle
    of the N-pose (its ``end:npose`` never came) left ``GET /api/patients/{id}/live``
    saying the pose was being held (``calibration.holding``) while the session was
    interrupted. ``pose-cut-off/1`` (docs/extensions/pose-cut-off.md) says what is true:
    ``holding_now`` null and the pose ``cut_off``; ``holding`` stays as clients read it."""
    from armtrack.server.emulator import MessagePlan, hello_message

    api = module_server.client("alice")
    patient = api.patient("Cut Off In The Pose")
    token = api.device(patient["id"])["token"]
    plan = MessagePlan(elbow.recording)
    sent = int(np.searchsorted(plan.times, 2.0))  # the N-pose is held from 0.5 to 3.0 s

    def live() -> dict:
        return api.http.get(f"/api/patients/{patient['id']}/live").json()

    async def stream_into_the_pose() -> tuple[int, dict]:
        async with connect(f"{module_server.ws_url}?token={token}") as ws:
            await ws.send(json.dumps(hello_message(elbow.recording, "kit")))
            ready = json.loads(await ws.recv())
            for seq in range(sent):
                await ws.send(plan.encode(seq))
            async with asyncio.timeout(30):
                while json.loads(await ws.recv()).get("seq") != sent - 1:
                    pass  # until the last message is acked: stored
            held = await asyncio.to_thread(live)
        return ready["session"], held  # closed without a bye: the power gone

    session, held = asyncio.run(stream_into_the_pose())
    assert held["session"]["status"] == "live"
    assert held["calibration"]["holding"]["name"] == "npose"
    assert held["calibration"]["holding_now"]["name"] == "npose"
    assert held["calibration"]["poses"][0]["cut_off"] is False
    deadline = time.monotonic() + 30
    while api.http.get(f"/api/sessions/{session}").json()["status"] != "interrupted":
        assert time.monotonic() < deadline, "the session was not marked interrupted"
        time.sleep(0.1)
    after = live()
    print(f"\nafter the cut: session {after['session']['status']}, calibration "
          f"{ {k: after['calibration'][k] for k in ('holding_now', 'poses')} }")
    assert after["session"]["status"] == "interrupted"
    assert after["calibration"]["holding_now"] is None
    (pose,) = after["calibration"]["poses"]
    assert pose["name"] == "npose" and pose["end"] is None and pose["cut_off"] is True
    # what clients read before: unchanged (the pose whose end has not come)
    assert after["calibration"]["holding"]["name"] == "npose"


def _rss_mb(pids) -> float:
    from pathlib import Path

    return sum(int(Path(f"/proc/{pid}/status").read_text().split("VmRSS:")[1].split()[0])
               for pid in pids) / 1024


def test_a_sensor_that_stops_mid_session_leaves_the_live_view_going_and_memory_bounded(
        module_server, elbow):
    """A 3-sensor kit whose hand sensor stops after calibration (its battery died) while
    the upper arm and forearm send 100,000 rows more each: the live poses go on with
    the hand's angles unknown (null), the feed says in words which sensor stopped and what
    to do, and the live estimation process does not hold the others' rows for the hand
    (it did: no pose after the stop, ~100 MB a million rows)."""
    api = module_server.client("alice")
    patient = api.patient()
    token = api.device(patient["id"])["token"]
    recording = elbow.recording
    stop_t, more = 12.0, 100_000
    rows = {name: np.column_stack([s.t, s.acc, s.gyr, s.mag])
            for name, s in recording.sensors.items()}
    end_t = rows["forearm"][-1, 0] + more / 100
    rss, seen = {}, []

    async def scenario():
        def caught_up(ups):
            poses = [u for u in ups if u["kind"] == "pose"]
            if poses and "before" not in rss:
                rss["pids"] = _live_estimation_processes(module_server)
                rss["before"] = _rss_mb(rss["pids"])
            seen[:] = ups
            return any(p["t"] >= end_t - 1.0 for p in poses)  # the stream's newest

        subscribed = asyncio.Event()
        watcher = asyncio.create_task(watch(module_server, api.token, patient["id"],
                                            caught_up, timeout=180.0, subscribed=subscribed))
        await subscribed_or_failed(subscribed, watcher)
        async with connect(module_server.ws_url, max_size=None,
                           additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": list(rows),
                                      "rate_hz": 100, "nine_axis": True, "resume": None}))
            assert json.loads(await ws.recv())["type"] == "ready"
            acked = {"seq": -1, "errors": []}

            async def read_acks():
                async for text in ws:
                    message = json.loads(text)
                    if message["type"] == "ack":
                        acked["seq"] = max(acked["seq"], message["seq"])
                    elif message["type"] == "error":
                        acked["errors"].append(message)
            reader = asyncio.create_task(read_acks())
            seq = 0

            async def send(payload):
                nonlocal seq
                await ws.send(json.dumps({**payload, "seq": seq}))
                seq += 1

            for pose in recording.calibration:
                for t, label in ((pose.start, pose.name), (pose.end, f"end:{pose.name}")):
                    await send({"type": "mark", "t": t, "label": label})
            n = len(rows["forearm"])
            for start in range(0, n, 100):
                for name, r in rows.items():
                    chunk = r[start:start + 100]
                    if name == "hand":  # its battery dies at stop_t
                        chunk = chunk[chunk[:, 0] < stop_t]
                    if len(chunk):
                        await send({"type": "samples", "sensor": name,
                                    "rows": chunk.tolist()})
            # the upper arm and forearm go on, held still: 100,000 rows more each
            still = {name: [round(float(v), 3) for v in rows[name][-1, 1:]]
                     for name in ("upper_arm", "forearm")}
            t0 = rows["forearm"][-1, 0]
            for start in range(1, more + 1, 1000):
                t = t0 + np.arange(start, start + 1000) / 100
                for name, values in still.items():
                    await send({"type": "samples", "sensor": name,
                                "rows": [[round(float(x), 2), *values] for x in t]})
            async with asyncio.timeout(60):
                while acked["seq"] < seq - 1:
                    await asyncio.sleep(0.05)
            try:  # the newest pose after the last ack (a minute: a loaded machine)
                updates = await asyncio.wait_for(asyncio.shield(watcher), 60.0)
            except TimeoutError:
                watcher.cancel()
                updates = None
            rss["after"] = _rss_mb(rss["pids"])
            reader.cancel()
            assert not acked["errors"], acked["errors"]
            return updates

    updates = asyncio.run(scenario())
    print(f"live estimation RSS {rss['before']:.0f} MB after the first pose, "
          f"{rss['after']:.0f} MB after 2 × {more} rows without the hand "
          f"(+{rss['after'] - rss['before']:.0f} MB)")
    poses = [u for u in seen if u["kind"] == "pose"]
    assert updates is not None, (
        "no live pose reached the stream's end: the view froze; "
        f"{len(poses)} poses, the last at {poses[-1]['t'] if poses else None} s of {end_t} s, "
        f"other updates {[u for u in seen if u['kind'] != 'pose'][-3:]}")
    poses = [u for u in updates if u["kind"] == "pose"]
    late = [p for p in poses if p["t"] > stop_t + 15]
    assert late, "no live pose after the hand stopped"
    last = late[-1]
    assert last["angles_deg"]["elbow_flexion"] is not None
    assert last["angles_deg"]["wrist_flexion"] is None  # the hand's: unknown, not 0
    assert last["segments_q"]["hand"][0] is None
    # the hand only: the others' 1000-row messages (10 s each) are not a stop
    assert set(last["stopped_sensors"]) == {"hand"}
    assert last["stopped_sensors"]["hand"]["t"] < stop_t
    assert any(w.startswith("the hand sensor stopped sending at ") and "check its battery"
               in w for w in last["warnings"]), last["warnings"]
    assert rss["after"] - rss["before"] < 10, "the live estimation held the rows"


def _estimator_poses(sensors, rows_of, until_s, stop_of, resume_of=None, **live_args):
    """A ``LiveEstimator`` fed 1-s messages of ``sensors`` (``rows_of(name, t0, n)``) up
    to ``until_s`` stream seconds, each sensor until ``stop_of.get(name, inf)`` (and from
    ``resume_of.get(name, inf)`` on again): its poses' dicts (the pose rate lifted)."""
    resume_of = resume_of or {}
    from armtrack.estimator.body import SegmentLengths
    from armtrack.estimator.pipeline import PipelineConfig
    from armtrack.server.ingest.protocol import Samples
    from armtrack.server.live.estimator import HELD, LiveEstimator

    config = PipelineConfig(side="right", lengths=SegmentLengths.from_height(1.7),
                            sensors=tuple(sensors))
    live = LiveEstimator(config, session_id=1, max_rate_hz=1e9, **live_args)
    poses = []
    for second in range(int(until_s)):
        items = [Samples(-1, name, rows_of(name, float(second), 100)) for name in sensors
                 if not stop_of.get(name, np.inf) <= second < resume_of.get(name, np.inf)]
        pose = live.process(items)
        if pose is not None and pose != HELD:
            poses.append(pose.parsed() if hasattr(pose, "parsed") else json.loads(pose.text))
    return live, poses


def _still_rows(name, t0, n):
    rows = np.zeros((n, 10))
    rows[:, 0] = t0 + np.arange(n) / 100
    rows[:, 2] = -9.81  # hanging: the sensor's -Y up
    rows[:, 7:] = np.nan  # 6-axis
    return rows


def test_the_live_view_goes_on_when_the_reference_sensor_stops_after_calibration():
    """The upper arm (the sensor whose sample times the estimates take) stops at 70 s,
    after the default calibration at 60 s: the estimates go on at the forearm's times,
    the upper arm's and the elbow's angles unknown, and the rows are not held."""
    live, poses = _estimator_poses(("upper_arm", "forearm"), _still_rows, 560,
                                   {"upper_arm": 70})
    last = poses[-1]
    assert last["t"] > 558
    assert last["angles_deg"]["shoulder_flexion"] is None
    assert last["angles_deg"]["elbow_flexion"] is None
    assert last["segments_q"]["upper_arm"][0] is None
    assert last["segments_q"]["forearm"][0] is not None
    assert last["positions_m"]["elbow"][0] is None
    assert set(last["stopped_sensors"]) == {"upper_arm"}
    assert "the upper arm sensor stopped sending" in last["warnings"][-1]
    assert live.pipeline.held_rows() < 1000


def test_the_stopped_sensors_time_is_the_clinics_clock():
    """The warning's "stopped sending at 12:03" is read by the therapist beside their own
    clock: it is the clinic's time (``ARMTRACK_CLINIC_TIMEZONE``), not the server
    machine's (a container's is UTC), as every day and time the pages show (review19)."""
    from datetime import datetime
    from zoneinfo import ZoneInfo

    zone = "Pacific/Chatham"  # +12:45/+13:45: no machine's clock here reads it by chance
    live, poses = _estimator_poses(("upper_arm", "forearm"), _still_rows, 560,
                                   {"upper_arm": 70}, clinic_timezone=zone)
    at = live.stopped["upper_arm"]["at"]
    clinic = datetime.fromtimestamp(at, ZoneInfo(zone)).strftime("%H:%M")
    warning = next(w for w in poses[-1]["warnings"] if "stopped sending at" in w)
    print(f"\n{warning}")
    assert f"stopped sending at {clinic} " in warning, (clinic, warning)


def test_a_sensor_that_sends_once_and_stops_before_calibration_is_left_out():
    """The hand sends one message and stops: calibration (at 60 s) and the live view go
    on without it; its angles are unknown (null), not the 0 of an unworn sensor."""
    live, poses = _estimator_poses(("upper_arm", "forearm", "hand"), _still_rows, 400,
                                   {"hand": 1})
    assert poses, "no live pose: the kit waits for its hand sensor for ever"
    last = poses[-1]
    assert last["t"] > 398
    assert last["angles_deg"]["wrist_flexion"] is None
    assert last["angles_deg"]["elbow_flexion"] is not None
    assert "the hand sensor stopped sending" in last["warnings"][-1]
    assert live.pipeline.held_rows() < 1000


def test_a_stopped_sensor_that_sends_again_is_stored_but_stays_out_of_the_live_view():
    """The hand stops at 1 s and sends again from 300 s (after it was left out): the live
    view says so once and goes on without it (its filter missed minutes); no failure."""
    live, poses = _estimator_poses(("upper_arm", "forearm", "hand"), _still_rows, 400,
                                   {"hand": 1}, {"hand": 300})
    last = poses[-1]
    assert last["t"] > 398 and last["angles_deg"]["wrist_flexion"] is None
    again = [w for w in last["warnings"] if "the hand sensor sends again" in w]
    assert len(again) == 1 and "shown live from the next session" in again[0]
    assert live.pipeline.held_rows() < 1000


def test_the_live_page_titles_a_stopped_sensor_as_what_it_is(module_server, tmp_path):
    """The hand stops at 80 s (after the default calibration) while the upper arm and
    forearm go on 240 s more, sent at once (the held rows' rule leaves it out without
    waiting 30 s of wall clock). The live page's box said "Calibrated, with warnings —
    the angles may be less accurate" above the stopped-sensor warning; its title now says
    what is true, at 390 and 1280 px."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from browser_helpers import chromium, first_page, need_browser, sign_in_as

    sync_api = need_browser()
    api = module_server.client("alice")
    patient = api.patient("Hana Hand")
    token = api.device(patient["id"])["token"]
    opened, done = threading.Event(), threading.Event()
    ready = {}

    async def kit():
        async with connect(module_server.ws_url, max_size=None,
                           additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "rate_hz": 100, "nine_axis": False,
                                      "sensors": ["upper_arm", "forearm", "hand"],
                                      "resume": None}))
            ready.update(json.loads(await ws.recv()))
            errors = []

            async def read():  # acks; an error would be the test's fault
                async for text in ws:
                    if json.loads(text)["type"] == "error":
                        errors.append(text)
            reader = asyncio.create_task(read())
            assert await asyncio.to_thread(opened.wait, 60)  # the page watches
            seq = 0
            for start in range(0, 32_000, 1000):  # the hand stops at 80 s (calibrated)
                names = ("upper_arm", "forearm") + (("hand",) if start < 8000 else ())
                t = (start + np.arange(1000)) / 100
                rows = [[round(float(x), 2), 0, -9.81, 0, 0, 0, 0, None, None, None]
                        for x in t]
                for name in names:
                    await ws.send(json.dumps({"type": "samples", "sensor": name,
                                              "rows": rows, "seq": seq}))
                    seq += 1
            assert not errors, errors
            await asyncio.to_thread(done.wait, 120)  # live until the page was read
            assert not errors, errors
            reader.cancel()

    with (ThreadPoolExecutor(1) as pool, sync_api.sync_playwright() as playwright,
          chromium(playwright, 390, 844, phone=True) as narrow,
          chromium(playwright, 1280, 900) as wide):
        streaming = pool.submit(asyncio.run, kit())
        try:
            pages = {390: first_page(narrow), 1280: first_page(wide)}
            deadline = time.monotonic() + 60
            while "session" not in ready and time.monotonic() < deadline:
                time.sleep(0.05)
            for page in pages.values():  # both watch before the kit sends (poses go by)
                sign_in_as(page, module_server.url, "alice")
                page.goto(f"{module_server.url}/sessions/{ready['session']}")
                sync_api.expect(page.locator("#calibration-box")).to_be_visible(
                    timeout=30_000)
            opened.set()
            for width, page in pages.items():
                warnings = page.locator("#calibration-warnings")
                sync_api.expect(warnings).to_contain_text(
                    "the hand sensor stopped sending", timeout=60_000)
                page.locator("#calibration-box").screenshot(
                    path=str(tmp_path / f"stopped-{width}.png"))
                title = page.locator("#calibration-box .title").inner_text()
                print(f"\n{width} px: {title} | {warnings.inner_text()}")
                assert title == "Live angles without the hand sensor: it stopped sending", title
                # the words get the box's width: at 390 px they once stood in a column about
                # 100 px wide, squeezed between the icon and the buttons
                what, box = (page.locator(f"#calibration-box{part}").bounding_box()["width"]
                             for part in (" .what", ""))
                assert what >= 0.6 * box, (width, what, box)
        finally:
            opened.set()
            done.set()
            streaming.result(timeout=120)
