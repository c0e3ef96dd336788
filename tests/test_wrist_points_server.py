"""Wrist points through a real server (docs/extensions/points.md): a kit streams an
upper-arm IMU and a robot's wrist points; the live view shows the γ elbow; the stored
session says where its elbow came from, exports the points to the same numbers and
estimates the elbow against truth; an upload does the same; malformed points are refused
whole, naming their seq, and nothing of them is stored."""

from __future__ import annotations

import asyncio
import json

import numpy as np
import pytest
from armtrack.estimator.recording import format_recording, parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator, hello_message
from test_server_live import watch
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

pytestmark = pytest.mark.both_databases


@pytest.fixture(scope="module")
def robot_session():
    """A right arm flexing the elbow, a 6-axis upper-arm IMU and a robot's wrist points."""
    return simulate(SimulationConfig(exercise="elbow_flexion", repetitions=3, seed=8,
                                     sensors=("upper_arm",), nine_axis=False,
                                     wrist_points="robot"))


def _flexion_rmse(times, flexion_deg, truth):
    keep = times >= 12.0
    error = flexion_deg[keep] - np.rad2deg(np.interp(times[keep], truth.t,
                                                     truth.angles["elbow_flexion"]))
    return float(np.sqrt(np.mean(error ** 2)))


def test_a_streamed_session_with_wrist_points_is_shown_live_stored_and_estimated(
        module_server, robot_session):
    api = module_server.client("alice")
    patient = api.patient("Grace")
    token = api.device(patient["id"])["token"]
    recording, truth = robot_session.recording, robot_session.truth

    def enough(updates):  # until the session ends
        return any(u.get("kind") == "session" and u.get("status") != "live" for u in updates)

    async def scenario():
        watcher = asyncio.create_task(watch(module_server, api.token, patient["id"], enough))
        await asyncio.sleep(0.3)
        # real time: the live estimation process may still be starting on a busy machine
        stats = await KitEmulator(recording, module_server.ws_url, token, speed=1.0).run()
        return stats, await watcher

    stats, updates = asyncio.run(scenario())
    assert stats.acked == stats.total and not stats.errors, stats.errors
    poses = [u for u in updates if u.get("kind") == "pose" and u["t"] > 12.0]
    assert len(poses) >= 5 and all(p["elbow_source"] == "points" for p in poses)
    live = _flexion_rmse(np.array([p["t"] for p in poses]),
                         np.array([p["angles_deg"]["elbow_flexion"] for p in poses]), truth)
    print(f"\nlive: {len(poses)} poses, elbow flexion from the wrist points {live:.2f}° RMSE")
    assert live <= 2.0

    session = api.wait_processed(stats.session)
    assert session["processing_error"] is None
    elbow = session["estimator"]["elbow"]
    assert elbow["source"] == "points" and elbow["no_point_share"] == 0.0

    exported = parse_recording(api.http.get(
        f"/api/sessions/{stats.session}/recording.csv").content)
    assert exported.version == 2 and exported.points_frame == recording.points_frame
    for name in ("t", "p"):  # the same float64 numbers as sent
        assert np.array_equal(getattr(exported.points["wrist"], name).view(np.int64),
                              getattr(recording.points["wrist"], name).view(np.int64))
    assert np.array_equal(exported.sensors["upper_arm"].acc, recording.sensors["upper_arm"].acc)

    angles = api.http.get(f"/api/sessions/{stats.session}/angles.csv").text.splitlines()
    columns = angles[0].split(",")
    table = np.array([[float(v) for v in line.split(",")] for line in angles[1:]])
    stored = _flexion_rmse(table[:, columns.index("t")],
                           table[:, columns.index("elbow_flexion")], truth)
    print(f"stored: elbow flexion {stored:.2f}° RMSE over {len(table)} estimates")
    assert stored <= 2.0


def test_an_uploaded_recording_with_points_keeps_them(module_server, robot_session):
    api = module_server.client("alice")
    patient = api.patient("Hopper")
    data = format_recording(robot_session.recording)
    answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                           files={"file": ("robot.csv", data, "text/csv")})
    assert answer.status_code == 201, answer.text
    session = api.wait_processed(answer.json()["id"])
    assert session["estimator"]["elbow"]["source"] == "points"
    exported = api.http.get(f"/api/sessions/{session['id']}/recording.csv").content
    assert exported == data  # byte for byte


async def _refusals(server, token, recording):
    """Send a hello with points, then bad points messages; the errors and the ack."""
    hello = hello_message(recording, "robot-kit")
    good = [[0.0, 0.1, -0.4, 1.0], [0.01, 0.1, -0.4, 1.0]]
    bad = [
        {"type": "points", "seq": 0, "point": "elbow", "rows": good},
        {"type": "points", "seq": 1, "point": "wrist", "rows": [[0.0, 0.1, -0.4]]},
        {"type": "points", "seq": 2, "point": "wrist", "rows": [[0.0, 0.1, "x", 1.0]]},
        {"type": "points", "seq": 3, "point": "wrist", "rows": [[0.0, 0.1, -0.4, 11.0]]},
        {"type": "points", "seq": 4, "point": "wrist", "rows": [[0.5, 0, 0, 1], [0.4, 0, 0, 1]]},
        {"type": "points", "seq": 5, "point": "wrist", "rows": good},
        {"type": "points", "seq": 6, "point": "wrist", "rows": [[0.005, 0.1, -0.4, 1.0]]},
    ]
    errors = {}
    async with connect(server.ws_url, additional_headers={
            "Authorization": f"Bearer {token}"}) as ws:
        await ws.send(json.dumps(hello))
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        for message in bad:
            await ws.send(json.dumps(message))
        await ws.send(json.dumps({"type": "bye"}))
        try:
            while True:
                reply = json.loads(await ws.recv())
                if reply["type"] == "error":
                    errors[reply["seq"]] = reply["reason"]
        except ConnectionClosed:
            pass
    return ready["session"], errors


def test_malformed_points_are_refused_whole_and_nothing_of_them_is_stored(module_server,
                                                                         robot_session):
    api = module_server.client("alice")
    patient = api.patient("Lovelace")
    token = api.device(patient["id"])["token"]
    session_id, errors = asyncio.run(_refusals(module_server, token, robot_session.recording))
    assert "point 'elbow' was not declared" in errors[0]
    assert "row 0 must be [t, x, y, z]" in errors[1] and "row 0 must be" in errors[2]
    assert "more than 10 m" in errors[3]
    assert "t goes backwards at row 1" in errors[4]
    assert "t goes backwards for point wrist" in errors[6]
    assert 5 not in errors
    rows = module_server.sql("SELECT n_rows FROM sample_blocks WHERE session_id = :s AND "
                             "sensor = 'point:wrist'", s=session_id)
    assert sum(r[0] for r in rows) == 2  # only seq 5's two rows


def test_a_hello_with_points_needs_an_upper_arm_and_a_sound_frame(module_server,
                                                                  robot_session):
    api = module_server.client("alice")
    patient = api.patient("Noether")
    token = api.device(patient["id"])["token"]

    async def hello_reply(hello):
        async with connect(module_server.ws_url, additional_headers={
                "Authorization": f"Bearer {token}"}) as ws:
            await ws.send(json.dumps(hello))
            try:
                return json.loads(await ws.recv()), None
            except ConnectionClosed as closed:
                return None, closed.rcvd.code if closed.rcvd else None

    hello = hello_message(robot_session.recording, "robot-kit")
    no_upper = {**hello, "sensors": ["forearm"]}
    reply, _ = asyncio.run(hello_reply(no_upper))
    assert reply["type"] == "error" and "need an upper_arm sensor" in reply["reason"]
    no_yaw = {**hello, "points": {**hello["points"]}}
    del no_yaw["points"]["thorax_yaw_deg"]
    reply, _ = asyncio.run(hello_reply(no_yaw))
    assert reply["type"] == "error" and "yaw" in reply["reason"]
    latency = {**hello, "points": {**hello["points"], "latency_s": 5}}
    reply, _ = asyncio.run(hello_reply(latency))
    assert reply["type"] == "error" and "latency_s must be 0 to 2 s" in reply["reason"]
