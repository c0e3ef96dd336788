"""Security review (review7's finding 1): an erased or closed session's live side outlived
it. Erasing or closing a session ends its open stream (``Services.end_session_streams``);
the stream's end then kept its live side (estimator, held estimates) as a lost one's, for
a resume, for ``LIVE_PARK_S`` (120 s), and its held estimates' re-ask published one more
pose of the erased session to the patient's live feed after the erase had answered. And
the hub kept the session's last pose as the patient's latest: a 3D view opened after the
erase drew the erased session's arm and said "session N: live". A real server (its pose
rate 0.25 Hz, so that the held estimates' re-ask comes 4 s after the first pose: well
after the erase's answer), a real kit and feed over WebSocket, a real 3D view."""

from __future__ import annotations

import asyncio
import json
import time

import numpy as np
import pytest
from armtrack.estimator.simulation import SimulationConfig, simulate
from server_support import server_fixture
from test_viewer import texts
from test_viewer import watch as watch_view
from websockets.asyncio.client import connect

POSES_HZ = 0.25  # one pose each 4 s: the held estimates wait that long
AFTER_S = 5.0  # how long the feed is watched after the erase (past the held re-ask)


server = server_fixture("erase-live", "alice", env={"ARMTRACK_LIVE_POSES_HZ": str(POSES_HZ)})


@pytest.fixture(scope="module")
def recording():
    return simulate(SimulationConfig(exercise="elbow_flexion", repetitions=3, seed=4)).recording


def _stream_until_a_pose_then(server, api, recording, end: str, watcher=None):
    """A kit streams the patient's session; once the feed shows its first pose, the
    therapist ``end``s it ("erase" or "close", the kit still connected). What the feed
    got after the answer, the session's id, and the frames of a 3D view opened after.
    ``watcher``: the instance (``ServerProcess``) of the feed and the 3D view, if not
    ``server`` (another instance on its database and broker)."""
    watcher = watcher or server
    viewer = api if watcher is server else watcher.client("alice")
    patient = api.patient(f"Ada {end}")
    token = api.device(patient["id"])["token"]
    feed_url = f"ws://127.0.0.1:{watcher.port}/ws/live?patient={patient['id']}"
    updates: list[tuple[float, dict]] = []

    async def watch(feed):
        async for raw in feed:
            updates.append((time.monotonic(), json.loads(raw)))

    async def kit(ws):
        seq = 0
        for pose in recording.calibration:
            for t, label in ((pose.start, pose.name), (pose.end, f"end:{pose.name}")):
                await ws.send(json.dumps({"type": "mark", "seq": seq, "t": t, "label": label}))
                seq += 1
        n = len(recording.sensors["forearm"].t)
        for start in range(0, n, 10):
            for name in ("upper_arm", "forearm", "hand"):
                s = recording.sensors[name]
                rows = np.column_stack([s.t, s.acc, s.gyr, s.mag])[start:start + 10]
                await ws.send(json.dumps({"type": "samples", "seq": seq, "sensor": name,
                                          "rows": rows.tolist()}))
                seq += 1
            await asyncio.sleep(0.01)

    async def run():
        feed = await connect(feed_url, additional_headers={
            "Authorization": f"Bearer {viewer.token}"})
        watching = asyncio.create_task(watch(feed))
        ws = await connect(f"{server.ws_url}?token={token}")
        await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                  "side": "right", "sensors": ["upper_arm", "forearm", "hand"],
                                  "rate_hz": 100, "nine_axis": True, "resume": None}))
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        session_id = ready["session"]
        sender = asyncio.create_task(kit(ws))
        async with asyncio.timeout(60):
            while not any(u.get("kind") == "pose" for _, u in updates):
                await asyncio.sleep(0.05)
        await asyncio.sleep(0.3)  # more samples: their estimates are held for the pose rate
        if end == "erase":
            answer = await asyncio.to_thread(api.http.delete, f"/api/sessions/{session_id}")
            assert answer.status_code == 204, answer.text
        else:
            answer = await asyncio.to_thread(api.http.post,
                                             f"/api/sessions/{session_id}/close",
                                             params={"wait": "false"})
            assert answer.status_code == 202, answer.text
        answered = time.monotonic()
        sender.cancel()
        await asyncio.gather(sender, return_exceptions=True)
        await asyncio.sleep(AFTER_S)
        watching.cancel()
        await feed.close()
        await ws.close()
        grant = await asyncio.to_thread(viewer.http.post, "/api/viewer",
                                        json={"patient_id": patient["id"]})
        assert grant.status_code == 200, grant.text
        view = await watch_view(f"ws://127.0.0.1:{watcher.port}"
                                f"{grant.json()['url'].rstrip('/')}",
                                lambda messages: "Live ·" in texts(messages), 15.0)
        after = [u for at, u in updates if at > answered]
        return session_id, after, texts(view)

    return asyncio.run(run())


def test_no_pose_of_an_erased_session_reaches_the_feed_or_a_new_view(server, recording):
    api = server.client("alice")
    session_id, after, view = _stream_until_a_pose_then(server, api, recording, "erase")
    poses = [u for u in after if u.get("kind") == "pose" and u["session_id"] == session_id]
    print(f"poses of erased session {session_id} on the feed after the erase: {len(poses)}")
    assert poses == [], f"the feed got {len(poses)} pose(s) of the erased session"
    # the 3D view opened after the erase does not draw the erased session
    print(f"the 3D view's text: {view[:300]!r}")
    assert "Live ·" in view  # its status text was read
    assert f"session {session_id}" not in view
    assert "no live session yet" in view


def test_a_closed_sessions_live_side_is_let_go(server, recording):
    api = server.client("alice")
    session_id, after, _ = _stream_until_a_pose_then(server, api, recording, "close")
    poses = [u for u in after if u.get("kind") == "pose"]
    print(f"poses of closed session {session_id} on the feed after the close: {len(poses)}")
    assert poses == [], f"the feed got {len(poses)} pose(s) after the session's close"
