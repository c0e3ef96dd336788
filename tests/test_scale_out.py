"""Several server instances on one database and one broker (README "Scaling out").

* fencing: a stream taken over by another instance is never stored twice (two group
  writers on one database, one of them late, as an old instance still committing);
* the integration: PostgreSQL (``ARMTRACK_TEST_POSTGRES_URL``, CI starts it), a
  ``redis-server`` this test starts on a free loopback port, and two ``armtrack serve``
  processes A and B. A kit streams a patient into A while a therapist watches the
  patient's ``/ws/live`` on B; A is SIGKILLed mid-stream and the kit resumes on B. Nothing
  is lost or doubled (the export is the recording bit for bit), and B's viewer got A's
  poses through the broker (their latency printed).
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import time

import numpy as np
import pytest
from armtrack.estimator.recording import parse_recording, read_recording
from armtrack.server.db import models
from armtrack.server.db.engine import make_engine
from armtrack.server.db.migrate import upgrade
from armtrack.server.emulator import KitEmulator
from armtrack.server.ingest.protocol import Samples
from armtrack.server.ingest.writer import GroupWriter, StreamState, Write
from armtrack.server.store.blocks import unpack
from conftest import fresh_postgres_database
from server_support import ServerProcess, add_patient, free_port
from sqlalchemy import func, select
from test_server_e2e import assert_same_samples


def _session_with_stream(engine) -> int:
    from sqlalchemy.orm import Session

    with Session(engine) as db:
        patient = add_patient(db)
        session = models.Session(patient_id=patient.id, source="stream", status="live",
                                 side="right", sensors={"upperarm": {}}, meta={})
        db.add(session)
        db.flush()
        db.add(models.Stream(id="s1", session_id=session.id, next_seq=0, last_t={}))
        db.commit()
        return session.id


def _samples(seq: int) -> Samples:
    rows = np.zeros((5, 10))
    rows[:, 0] = seq + np.arange(5) * 0.01
    return Samples(seq, "upperarm", rows)


@pytest.fixture(params=["sqlite", "postgres"])
def database_url(request, tmp_path):
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'f.db'}"
    return fresh_postgres_database(request.getfixturevalue("postgres_url"))


def test_a_stream_taken_over_elsewhere_is_fenced_off_not_stored_twice(database_url):
    engine = make_engine(database_url)
    upgrade(engine)
    session_id = _session_with_stream(engine)

    async def run() -> tuple[StreamState, StreamState, list[str]]:
        a_writer, b_writer = GroupWriter(engine, 0.01), GroupWriter(engine, 0.01)
        a_writer.start()
        b_writer.start()
        fenced: list[str] = []
        a = StreamState("s1", session_id, 0, {})
        a.on_fenced = lambda why: fenced.append(("a", why))
        for seq in range(5):  # A stores 0..4
            a_writer.submit(Write(a, seq, samples=_samples(seq)))
        await asyncio.sleep(0.05)
        await a.idle.wait()
        # the kit resumes on B, which reads next_seq 5 from the database and stores 5..7
        with engine.connect() as connection:
            next_seq = connection.scalar(select(models.Stream.next_seq))
        b = StreamState("s1", session_id, next_seq, {"upperarm": 4.04})
        b.on_fenced = lambda why: fenced.append(("b", why))
        for seq in range(5, 8):
            b_writer.submit(Write(b, seq, samples=_samples(seq)))
        await asyncio.sleep(0.05)
        await b.idle.wait()
        # A, still alive, commits late what it had accepted from the kit before: 5..6
        for seq in range(5, 7):
            a_writer.submit(Write(a, seq, samples=_samples(seq)))
        await asyncio.sleep(0.05)
        await a.idle.wait()
        await a_writer.stop()
        await b_writer.stop()
        return a, b, fenced

    a, b, fenced = asyncio.run(run())
    assert fenced == [("a", "taken")] and a.fenced and not b.fenced
    assert a.durable_seq == 4 and b.durable_seq == 7  # A never acks what it did not store
    with engine.connect() as connection:
        blocks = connection.execute(select(models.SampleBlock.ordinal, models.SampleBlock.data)
                                    .order_by(models.SampleBlock.id)).all()
        samples = connection.scalar(select(models.Session.samples))
        next_seq = connection.scalar(select(models.Stream.next_seq))
    # every seq once, in order (a commit's messages of a sensor are one block, numbered by
    # its first seq): A's 0..4, then B's 5..7, none of A's late 5..6
    ordinals = [ordinal for ordinal, _ in blocks]
    assert ordinals == sorted(ordinals) and ordinals[0] == 0
    stored = np.concatenate([unpack(data, 10) for _, data in blocks])
    assert stored.tobytes() == np.concatenate([_samples(seq).rows for seq in range(8)]).tobytes()
    assert samples == 8 * 5 and next_seq == 8
    engine.dispose()


def test_a_stream_whose_session_was_closed_elsewhere_stores_and_acks_nothing_more(
        database_url):
    """A therapist closed the session on another instance (its estimate begins without
    what follows): what this instance's writer commits after is dropped unacked, fenced as
    ``closed`` — on PostgreSQL the session's row is read locked with the stream's."""
    engine = make_engine(database_url)
    upgrade(engine)
    session_id = _session_with_stream(engine)

    async def run() -> tuple[StreamState, list[str]]:
        writer = GroupWriter(engine, 0.01)
        writer.start()
        fenced: list[str] = []
        stream = StreamState("s1", session_id, 0, {})
        stream.on_fenced = fenced.append
        for seq in range(3):
            writer.submit(Write(stream, seq, samples=_samples(seq)))
        await asyncio.sleep(0.05)
        await stream.idle.wait()
        with engine.begin() as connection:  # the close, as another instance commits it
            connection.execute(models.Session.__table__.update()
                               .where(models.Session.id == session_id).values(status="closed"))
        for seq in range(3, 6):
            writer.submit(Write(stream, seq, samples=_samples(seq)))
        await asyncio.sleep(0.05)
        await stream.idle.wait()
        await writer.stop()
        return stream, fenced

    stream, fenced = asyncio.run(run())
    with engine.connect() as connection:
        samples = connection.scalar(select(models.Session.samples))
        next_seq = connection.scalar(select(models.Stream.next_seq))
    print(f"fenced {fenced}, acked up to {stream.durable_seq}, stored {samples} samples")
    assert fenced == ["closed"] and stream.fenced
    assert stream.durable_seq == 2 and samples == 3 * 5 and next_seq == 3
    engine.dispose()


# -- two instances, PostgreSQL and the broker ------------------------------------------

@pytest.fixture
def redis_url(tmp_path):
    if shutil.which("redis-server") is None:
        pytest.skip("needs redis-server (apt-get install redis-server; .ci/install does)")
    pytest.importorskip("redis", reason="needs the broker's client: pip install -e '.[scale]'")
    port = free_port()
    process = subprocess.Popen(
        ["redis-server", "--port", str(port), "--bind", "127.0.0.1", "--save", "",
         "--appendonly", "no", "--dir", str(tmp_path)], stdout=subprocess.DEVNULL)
    import redis

    client = redis.Redis(port=port)
    deadline = time.monotonic() + 10
    while True:
        try:
            client.ping()
            break
        except redis.ConnectionError:
            if time.monotonic() > deadline or process.poll() is not None:
                process.kill()
                raise
            time.sleep(0.05)
    client.close()
    yield f"redis://127.0.0.1:{port}/0"
    process.terminate()
    process.wait(10)


async def _watch(url: str, token: str, poses: list, stop: asyncio.Event,
                 ready: asyncio.Event) -> None:
    """A therapist's ``/ws/live`` on ``url``: every pose with its arrival (wall) time."""
    from websockets.asyncio.client import connect

    async with connect(f"{url}/ws/live?patient={poses[0]}",
                       additional_headers={"Authorization": f"Bearer {token}"}) as ws:
        ready.set()
        while not stop.is_set():
            try:
                text = await asyncio.wait_for(ws.recv(), 0.2)
            except TimeoutError:
                continue
            update = json.loads(text)
            if update.get("kind") == "pose":
                poses.append((time.time(), update))


def test_a_stream_moves_to_another_instance_without_loss_and_is_watched_across(
        tmp_path, recordings_dir, postgres_url, redis_url):
    env = {"ARMTRACK_DATABASE_URL": fresh_postgres_database(postgres_url),
           "ARMTRACK_BROKER_URL": redis_url}
    a = ServerProcess(tmp_path / "a", env)
    b = ServerProcess(tmp_path / "b", env)
    a.create_user("alice")  # one database: alice exists for both
    a.start()
    b.start()
    try:
        api_a, api_b = a.client("alice"), b.client("alice")
        recording = read_recording(recordings_dir / "elbow_flexion.csv")
        patient = api_a.patient("Moving", recording.side, recording.height_m or 1.75)
        token = api_a.device(patient["id"])["token"]

        kit = KitEmulator(recording, a.ws_url, token, speed=3.0, backoff_s=(0.1, 1.0))
        killed: dict[str, float] = {}

        def on_ack(seq: int, stats) -> None:
            if "at" not in killed and stats.acked >= 0.4 * stats.total:
                a.kill()  # SIGKILL mid-stream: whatever A had not committed is gone
                kit.url = b.ws_url  # the load balancer sends the kit's next try to B
                killed["at"] = time.time()
                killed["acked"] = stats.acked

        kit.on_ack = on_ack
        poses: list = [patient["id"]]

        async def run():
            stop, ready = asyncio.Event(), asyncio.Event()
            b_ws = b.url.replace("http", "ws", 1)
            viewer = asyncio.create_task(_watch(b_ws, api_b.token, poses, stop, ready))
            await asyncio.wait_for(ready.wait(), 10)
            await asyncio.sleep(0.3)  # B subscribes to the patient's channel
            try:
                return await kit.run()
            finally:
                await asyncio.sleep(0.5)
                stop.set()
                await viewer

        stats = asyncio.run(run())
        assert "at" in killed, "A was not killed mid-stream"
        assert stats.acked == stats.total and not stats.errors, stats.errors
        assert stats.connections >= 2  # the resume on B

        session = api_b.wait_processed(stats.session)
        assert session["status"] == "closed" and session["processing_error"] is None
        assert session["samples"] == sum(len(s) for s in recording.sensors.values())
        exported = api_b.http.get(f"/api/sessions/{stats.session}/recording.csv")
        assert exported.status_code == 200
        assert_same_samples(parse_recording(exported.content), recording)
        engine = make_engine(env["ARMTRACK_DATABASE_URL"])
        with engine.connect() as connection:
            blocks = models.SampleBlock
            n, distinct = connection.execute(
                select(func.count(), func.count(func.distinct(blocks.ordinal)))
                .where(blocks.session_id == stats.session)).one()
        engine.dispose()
        assert n == distinct  # no message stored twice

        # B's viewer: A's poses came through the broker (with A's publication time) before
        # the kill (after it, B's live estimates of the resumed stream wait for a calibration
        # pose, as after any resume)
        relayed = [(t, u) for t, u in poses[1:] if "published_at" in u]
        own = [u for t, u in poses[1:] if "published_at" not in u]
        assert relayed, "no pose of A's stream reached B's viewer"
        assert all(t <= killed["at"] + 0.5 for t, _ in relayed)
        latency_ms = np.array([1000 * (t - u["published_at"]) for t, u in relayed])
        p50, p99 = np.percentile(latency_ms, [50, 99])
        print(f"{len(relayed)} poses A → broker → B's viewer: latency p50 {p50:.1f} ms, "
              f"p99 {p99:.1f} ms, max {latency_ms.max():.1f} ms; {len(own)} from B after the "
              f"kill at {killed['acked']}/{stats.total} acked; {stats.resent} messages resent")
        assert p50 < 100
    finally:
        a.kill()
        b.stop()
