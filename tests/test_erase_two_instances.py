"""An erase reaches every instance's live hub (README "Scaling out": two ``armtrack serve``
processes on one database and one Redis broker). An erase let go of the session's last
pose only in its own instance's hub (``LiveHub.forget_session``, ``test_erase_live_side``);
another instance whose therapist had watched the patient kept the pose that came through
the broker as the patient's latest, and a 3D view opened there after the erase drew the
erased session's arm and said "session N: live". Now the erase goes through the broker
to every instance (``RedisHub``'s channel ``armtrack:live:forget``, which every instance
reads)."""

from __future__ import annotations

import asyncio

import pytest
from armtrack.estimator.simulation import SimulationConfig, simulate
from server_support import ServerProcess
from test_erase_live_side import _stream_until_a_pose_then
from test_scale_out import redis_url  # noqa: F401  (a fixture: redis-server on a free port)


@pytest.fixture
def two(tmp_path, redis_url):  # noqa: F811
    """Servers A and B: one data folder (one SQLite file), one broker."""
    env = {"ARMTRACK_BROKER_URL": redis_url}
    a, b = ServerProcess(tmp_path / "data", env), ServerProcess(tmp_path / "data", env)
    a.create_user("alice")
    try:
        a.start()
        b.start()
        yield a, b
    finally:
        b.stop()
        a.stop()


def test_a_session_erased_on_one_instance_is_no_live_pose_on_another(two):
    a, b = two
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=3,
                                          seed=4)).recording
    # the kit streams into A, the therapist watches on B (A's poses through the broker);
    # the session is erased on A; a 3D view is then opened on B
    session_id, after, view = _stream_until_a_pose_then(a, a.client("alice"), recording,
                                                        "erase", watcher=b)
    poses = [u for u in after if u.get("kind") == "pose" and u["session_id"] == session_id]
    print(f"\nposes of erased session {session_id} on B's feed after the erase: "
          f"{len(poses)}; B's 3D view then: {view[:300]!r}")
    assert poses == []
    assert "Live ·" in view  # its status text was read
    assert f"session {session_id}" not in view
    assert "no live session yet" in view


def test_a_patient_erased_on_one_hub_is_forgotten_by_another(redis_url):  # noqa: F811
    """Two broker hubs (as in two instances): B watched the patient and holds its last
    pose; the patient's erase on A (``forget_patient``) makes B let go of it too, and a
    session's erase (``forget_session``) the same."""
    from armtrack.server.live.broker import RedisHub

    async def run() -> list[tuple[str, bool]]:
        a, b = RedisHub(redis_url), RedisHub(redis_url)
        await a.start()
        await b.start()
        seen = []
        try:
            for patient_id, forget in ((7, "patient"), (8, "session")):
                with b.subscribe(patient_id) as watch:
                    await asyncio.sleep(0.3)  # B subscribes to the patient's channel
                    a.publish(patient_id, {"kind": "pose", "session_id": 70 + patient_id})
                    async with asyncio.timeout(10):
                        await watch.get()
                held = patient_id in b.latest
                if forget == "patient":
                    a.forget_patient(patient_id)
                else:
                    a.forget_session(70 + patient_id)
                deadline = asyncio.get_running_loop().time() + 3
                while (patient_id in b.latest
                       and asyncio.get_running_loop().time() < deadline):
                    await asyncio.sleep(0.02)
                seen.append((forget, held, patient_id in b.latest, patient_id in a.latest))
        finally:
            await a.stop()
            await b.stop()
        return seen

    seen = asyncio.run(run())
    print(f"\n(erased, B held the pose, B still holds it, A still holds it): {seen}")
    assert seen == [("patient", True, False, False), ("session", True, False, False)]
