"""Security review (Low): one kit token could fill the disk. A session holds at most
``ARMTRACK_MAX_SESSION_SAMPLES`` rows and a kit starts at most
``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR`` sessions an hour: 2 M rows x 20 an hour, ~40 M
rows (~3 GB of random values) an hour from one token. Now a kit stores at most
``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY`` rows in its sessions of the last 24 hours, streamed
and uploaded together: a stream's message past it is refused whole (the protocol's
``error`` naming its ``seq`` and the setting, the stream open, what came before stored),
an upload past it is ``429`` naming the setting, nothing stored. Other kits are not
limited; sessions older than a day no longer count. Real server, real WebSocket client,
real database file."""

from __future__ import annotations

import asyncio
import json

import httpx
import pytest
from server_support import ServerProcess
from test_security_session_flood import hello
from test_security_upload_burst import still_recording

LIMIT = 3000
SETTING = "ARMTRACK_MAX_KIT_SAMPLES_PER_DAY"


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("kit_quota"),
                           env={SETTING: str(LIMIT)})
    server.create_user("alice")
    server.start()
    yield server
    server.stop()


def samples(seq: int, t0: float, rows: int) -> str:
    return json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                       "rows": [[t0 + i / 50, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, None, None,
                                 None] for i in range(rows)]})


async def session(srv, token: str, sizes: list[int]) -> tuple[int, dict[int, str]]:
    """A new session sending messages of ``sizes`` rows, then ``bye``: (its id, the
    ``error`` reason of each refused seq)."""
    ws, ready = await hello(srv, token)
    assert ready["type"] == "ready", ready
    refused: dict[int, str] = {}
    t = 0.0
    for seq, rows in enumerate(sizes):
        await ws.send(samples(seq, t, rows))
        t += rows / 50
    await ws.send(json.dumps({"type": "bye"}))
    async for raw in ws:
        message = json.loads(raw)
        if message["type"] == "error":
            refused[message["seq"]] = message["reason"]
    return ready["session"], refused


def stored(srv, session_id: int) -> int:
    return srv.sql("SELECT samples FROM sessions WHERE id = :s", s=session_id)[0][0]


def test_a_kit_stores_a_bounded_number_of_samples_a_day(srv):
    alice = srv.client("alice")
    patient = alice.patient("Quota")
    token = alice.device(patient["id"], "kit")["token"]
    other = alice.device(alice.patient("Other")["id"], "other kit")["token"]

    first, refused = asyncio.run(session(srv, token, [100] * 20))
    assert not refused and stored(srv, first) == 2000
    # 900 more fit; 200 would pass 3000 (refused whole); 100 fit exactly; 1 more does not
    second, refused = asyncio.run(session(srv, token, [100] * 9 + [200, 100, 1]))
    print(f"\nrefused: {refused}")
    assert sorted(refused) == [9, 11]
    for reason in refused.values():
        assert SETTING in reason and str(LIMIT) in reason
    assert stored(srv, second) == 1000  # what came before and after the refusal

    # an upload of the kit past it: 429 naming the setting, nothing stored
    sessions = srv.sql("SELECT count(*) FROM sessions")[0][0]
    answer = httpx.post(f"{srv.url}/api/recordings", headers={
        "Authorization": f"Bearer {token}"}, data={"wait": "false"},
        files={"file": ("one.csv", still_recording(1))}, timeout=60)
    print(f"upload: {answer.status_code} {answer.json()['detail']}")
    assert answer.status_code == 429 and SETTING in answer.json()["detail"]
    assert srv.sql("SELECT count(*) FROM sessions")[0][0] == sessions

    # another kit is not limited by this one's rows
    elsewhere, refused = asyncio.run(session(srv, other, [100] * 25))
    assert not refused and stored(srv, elsewhere) == 2500

    # a day later the kit's earlier sessions no longer count
    srv.sql("UPDATE sessions SET created_at = :at WHERE id IN (:a, :b)",
            at="2000-01-01 00:00:00.000000", a=first, b=second)
    third, refused = asyncio.run(session(srv, token, [100] * 30))
    assert not refused and stored(srv, third) == 3000
    answer = httpx.post(f"{srv.url}/api/recordings", headers={
        "Authorization": f"Bearer {token}"}, data={"wait": "false"},
        files={"file": ("one.csv", still_recording(1))}, timeout=60)
    assert answer.status_code == 429, answer.text


def test_an_uploads_wrist_points_count_toward_the_kits_day_as_a_streams_do(srv):
    """A stream's ``points`` rows count in ``sessions.samples`` (the writer adds them, as
    ARMTRACK_MAX_SESSION_SAMPLES counts "all sensors and points together"); an upload's
    must too, or a kit uploading points-heavy recordings stores past its day (each upload
    counted by its IMU rows only)."""
    from armtrack.estimator.recording import format_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    recording = simulate(SimulationConfig(
        exercise="elbow_flexion", repetitions=1, seed=8, rate_hz=50, sensors=("upper_arm",),
        nine_axis=False, wrist_points="robot")).recording
    imu = sum(len(s) for s in recording.sensors.values())
    points = sum(len(p) for p in recording.points.values())
    assert points > 0 and imu + points <= LIMIT < 2 * (imu + points)
    alice = srv.client("alice")
    token = alice.device(alice.patient("Points")["id"], "robot kit")["token"]
    data = format_recording(recording)

    def upload() -> httpx.Response:
        return httpx.post(f"{srv.url}/api/recordings", headers={
            "Authorization": f"Bearer {token}"}, data={"wait": "false"},
            files={"file": ("robot.csv", data)}, timeout=60)

    first = upload()
    assert first.status_code == 202, first.text  # stored; estimated later (wait false)
    print(f"\nupload: {imu} IMU rows + {points} point rows; stored as "
          f"{stored(srv, first.json()['id'])} samples")
    assert stored(srv, first.json()["id"]) == imu + points
    second = upload()  # 2 x (imu + points) would pass the kit's day
    print(f"second upload: {second.status_code} {second.json().get('detail', '')}")
    assert second.status_code == 429 and SETTING in second.json()["detail"]


def test_an_upload_made_while_the_kit_streams_counts_toward_its_streams_day(srv):
    """A stream counts its kit's day from the database when the kit's first stream opens,
    then by its streams (``Services.kit_samples``); an upload of the same kit made while
    that stream is open must count there too, or the stream stores a whole day on top."""
    alice = srv.client("alice")
    token = alice.device(alice.patient("Both ways")["id"], "kit")["token"]

    async def scenario() -> tuple[int, dict[int, str], int]:
        ws, ready = await hello(srv, token)
        assert ready["type"] == "ready", ready
        acked, refused = -1, {}

        async def until_acked(seq: int) -> None:
            nonlocal acked
            while acked < seq and seq not in refused:
                message = json.loads(await asyncio.wait_for(ws.recv(), 30))
                if message["type"] == "ack":
                    acked = message["seq"]
                elif message["type"] == "error":
                    refused[message["seq"]] = message["reason"]
        for seq in range(10):  # 1000 rows stored, the kit's day counted from here on
            await ws.send(samples(seq, seq * 2.0, 100))
        await until_acked(9)
        upload = await asyncio.to_thread(
            httpx.post, f"{srv.url}/api/recordings",
            headers={"Authorization": f"Bearer {token}"}, data={"wait": "false"},
            files={"file": ("five.csv", still_recording(5))}, timeout=60)  # 1500 rows
        for seq in range(10, 20):  # 1000 more: 3500 in the day, past 3000
            await ws.send(samples(seq, seq * 2.0, 100))
        await until_acked(19)
        await ws.send(json.dumps({"type": "bye"}))
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "error":
                refused[message["seq"]] = message["reason"]
        return ready["session"], refused, upload.status_code

    session_id, refused, uploaded = asyncio.run(scenario())
    print(f"\nupload {uploaded}; stream stored {stored(srv, session_id)}; refused "
          f"{sorted(refused)}")
    assert uploaded == 202
    assert stored(srv, session_id) == 1500, "the stream stored a day on top of the upload"
    assert sorted(refused) == list(range(15, 20))
    assert all(SETTING in reason for reason in refused.values())


def test_a_kit_whose_day_is_spent_is_refused_at_hello(srv):
    """A kit past its day was let in (``ready``, a new session made) and then refused
    message by message: an empty session for the therapist each time it tried again, and
    its data refused one message at a time. Now a hello that would start a new session or
    stream when the kit's day is already spent is refused before anything is stored, with
    the setting's name and close ``4429``, as the other per-kit limits at hello; the kit
    keeps its data and tries again later. A day that frees up lets it in again."""
    from test_security_session_flood import closing_code

    alice = srv.client("alice")
    token = alice.device(alice.patient("Spent")["id"], "kit")["token"]

    async def left_open(sizes: list[int]) -> int:
        """A session whose connection is lost once all is acked, without bye."""
        ws, ready = await hello(srv, token)
        for seq, rows in enumerate(sizes):
            await ws.send(samples(seq, seq * 2.0, rows))
        while (message := json.loads(await asyncio.wait_for(ws.recv(), 30))).get(
                "seq") != len(sizes) - 1 or message["type"] != "ack":
            assert message["type"] != "error", message
        await ws.close()
        return ready["session"]

    open_one = asyncio.run(left_open([100] * 29))
    spent, refused = asyncio.run(session(srv, token, [100]))
    assert not refused and stored(srv, open_one) + stored(srv, spent) == LIMIT
    sessions = srv.sql("SELECT count(*) FROM sessions")[0][0]

    async def try_hello(**fields) -> tuple[dict, int | None]:
        ws, answer = await hello(srv, token, **fields)
        if answer.get("type") == "error":
            return answer, await closing_code(ws)
        await ws.close()  # let in (ready): what the kit met before
        return answer, answer.get("closed")

    answer, code = asyncio.run(try_hello())
    print(f"\nhello with the day spent: {answer}, close {code}")
    assert answer.get("type") == "error" and SETTING in answer["reason"], answer
    assert str(LIMIT) in answer["reason"] and code == 4429
    answer, code = asyncio.run(try_hello(session=open_one))  # a new stream of a session
    print(f"a new stream in session {open_one}: {answer}, close {code}")
    assert answer.get("type") == "error" and SETTING in answer["reason"] and code == 4429
    assert srv.sql("SELECT count(*) FROM sessions")[0][0] == sessions, "a session was made"

    srv.sql("UPDATE sessions SET created_at = :at WHERE id IN (:a, :b)",
            at="2000-01-01 00:00:00.000000", a=spent, b=open_one)
    again, refused = asyncio.run(session(srv, token, [100]))
    assert not refused and stored(srv, again) == 100
