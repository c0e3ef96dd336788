"""The group writer's storage on SQLite, and the sample blocks' packing: what a commit
stores, and that it stays a few statements whatever the number of messages (each
execution lets go of the interpreter lock, which beside a busy event loop costs up to the
switch interval to get back: ``server/ingest/writer.py``)."""

from __future__ import annotations

import asyncio
import math
import random
import time
import zlib

import numpy as np
import orjson
import pytest
from armtrack.server.db import models
from armtrack.server.db.engine import make_engine, make_sessionmaker
from armtrack.server.db.migrate import upgrade
from armtrack.server.ingest.protocol import MarkMessage, Samples
from armtrack.server.ingest.writer import (
    BLOCK_MAX_ROWS,
    SQLITE_ROWS_PER_STATEMENT,
    GroupWriter,
    StreamState,
    Write,
)
from armtrack.server.store.blocks import (
    COMPRESS_FROM_ROWS,
    STORED_MAX_BYTES,
    pack,
    stored_zlib,
    unpack,
)
from server_support import add_patient
from sqlalchemy import event, select


def test_stored_blocks_are_zlibs_own_level_0_bytes():
    rng = random.Random(5)
    lengths = [*range(0, 2000), *rng.sample(range(2000, STORED_MAX_BYTES), 300),
               STORED_MAX_BYTES]
    for n in lengths:
        raw = rng.randbytes(n)
        assert stored_zlib(raw) == zlib.compress(raw, 0), n


@pytest.mark.parametrize("n_rows", [1, 10, COMPRESS_FROM_ROWS - 1, COMPRESS_FROM_ROWS, 1000])
def test_pack_reads_back_bit_for_bit(n_rows):
    rows = np.random.default_rng(n_rows).normal(size=(n_rows, 10))
    rows[0, 7:] = np.nan
    back = unpack(pack(rows), 10)
    assert back.tobytes() == rows.tobytes()


def _streams(engine, n: int) -> list[tuple[str, int]]:
    """``n`` live sessions, a stream each: (stream id, session id)."""
    with make_sessionmaker(engine)() as db:
        therapist = None
        out = []
        for i in range(n):
            patient = add_patient(db, f"p{i}", therapist)
            therapist = therapist or db.get(models.Therapist, patient.therapist_id)
            device = models.Device(patient_id=patient.id, name="kit", token_hash=f"h{i}")
            db.add(device)
            db.flush()
            session = models.Session(patient_id=patient.id, device_id=device.id,
                                     source="stream", status="interrupted" if i == 0
                                     else "live", side="right", height_m=1.7, rate_hz=100,
                                     sensors={}, meta={})
            db.add(session)
            db.flush()
            db.add(models.Stream(id=f"stream{i:04d}", session_id=session.id,
                                 device_id=device.id, next_seq=0, last_t={}))
            out.append((f"stream{i:04d}", session.id))
        db.commit()
    return out


def test_a_large_commit_stores_everything_in_a_few_statements(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'w.db'}")
    upgrade(engine)
    n_streams, per_stream = 3 * SQLITE_ROWS_PER_STATEMENT // 2, 4  # 750 streams, 3,000 writes
    ids = _streams(engine, n_streams)
    states = [StreamState(stream_id, session_id, 0, {}) for stream_id, session_id in ids]
    sensors = ("thorax", "upperarm", "forearm")
    batch, expected = [], {}
    for i, state in enumerate(states):
        for seq in range(per_stream):
            if seq == 2 and i % 100 == 0:
                batch.append(Write(state, seq, mark=MarkMessage(seq, seq * 0.1, "npose")))
                continue
            rows = np.full((10, 10), float(i))
            rows[:, 0] = seq * 0.1 + np.arange(10) * 0.01
            rows[:, 1] = seq
            sensor = sensors[seq % 3]
            batch.append(Write(state, seq, samples=Samples(seq, sensor, rows)))
            # a stream's messages of one sensor in a commit are one block, numbered by
            # the first (seq 0 and 3 are both thorax's)
            first = min(k for k in range(per_stream) if sensors[k % 3] == sensor)
            if (state.session_id, first) in expected:
                earlier = expected[(state.session_id, first)][1]
                rows = np.concatenate([earlier, rows])
            expected[(state.session_id, first)] = (sensor, rows)
    statements: list[str] = []
    event.listen(engine, "before_cursor_execute",
                 lambda *args: statements.append(args[2]))

    async def commit() -> None:
        writer = GroupWriter(engine, 0.01)
        writer.start()
        for write in batch:
            writer.submit(write)
        await asyncio.gather(*(state.idle.wait() for state in states))
        await asyncio.sleep(0)
        await writer.stop()

    started = time.time()
    asyncio.run(commit())
    # fence, blocks, marks, streams, sessions: each over up to 500 rows an execution, not
    # one execution a row (3,000 writes of 750 streams were 4,500 before)
    n_marks = len(ids[::100])
    per_statement = SQLITE_ROWS_PER_STATEMENT
    want = (3 * math.ceil(n_streams / per_statement)
            + math.ceil(len(expected) / per_statement) + math.ceil(n_marks / per_statement))
    print(f"\n{len(batch)} writes of {n_streams} streams: {len(statements)} statements")
    assert writer_statements(statements) == want == 12  # 2,250 blocks: 5 inserts
    assert all(state.durable_seq == per_stream - 1 for state in states)
    with engine.connect() as connection:
        blocks = connection.execute(select(
            models.SampleBlock.session_id, models.SampleBlock.ordinal, models.SampleBlock.sensor,
            models.SampleBlock.n_rows, models.SampleBlock.t_first, models.SampleBlock.t_last,
            models.SampleBlock.data)).all()
        marks = connection.execute(select(models.Mark.session_id, models.Mark.t,
                                          models.Mark.label)).all()
        streams = dict(connection.execute(select(models.Stream.id, models.Stream.next_seq)).all())
        last_t = dict(connection.execute(select(models.Stream.id, models.Stream.last_t)).all())
        sessions = connection.execute(select(models.Session.id, models.Session.samples,
                                             models.Session.status)).all()
    assert len(blocks) == len(expected)
    for session_id, ordinal, sensor, n_rows, t_first, t_last, data in blocks:
        want_sensor, want = expected[(session_id, ordinal)]
        assert sensor == want_sensor and n_rows == len(want)
        assert (t_first, t_last) == (want[0, 0], want[-1, 0])
        assert unpack(data, 10).tobytes() == want.tobytes()
    assert sorted(marks) == sorted((sid, 0.2, "npose") for (_, sid) in ids[::100])
    assert set(streams.values()) == {per_stream}
    times = last_t["stream0001"]
    times = orjson.loads(times) if isinstance(times, str) else times
    seen = {k: times.pop(k) for k in list(times) if k.startswith("~seen:")}
    assert times == {sensors[seq % 3]: seq * 0.1 + 0.09 for seq in (1, 2, 3)}
    # and when each sensor's rows were stored (the sensor table's "last seen")
    assert set(seen) == {f"~seen:{name}" for name in sensors}
    assert all(started <= at <= time.time() for at in seen.values()), (seen, started)
    by_session = {sid: n for sid, n, _ in sessions}
    for stream_id, session_id in ids:
        marked = 1 if int(stream_id[-4:]) % 100 == 0 else 0
        assert by_session[session_id] == 10 * (per_stream - marked)
    assert {status for _, _, status in sessions} == {"live"}  # the interrupted one too
    engine.dispose()


def writer_statements(statements: list[str]) -> int:
    """The statements of the commit (the test's own set-up ran before the listener)."""
    return sum(1 for s in statements if not s.lstrip().upper().startswith(("BEGIN", "COMMIT")))


def test_a_commit_stores_a_streams_messages_of_a_sensor_as_few_blocks(tmp_path):
    """The messages of one stream and sensor in a commit become blocks of at most
    BLOCK_MAX_ROWS rows (uncompressed, numbered by their first seq); read back in ordinal
    order they are the messages' rows, bit for bit; the other sensor's stay apart."""
    engine = make_engine(f"sqlite:///{tmp_path / 'w.db'}")
    upgrade(engine)
    [(stream_id, session_id)] = _streams(engine, 1)
    state = StreamState(stream_id, session_id, 0, {})
    rng = np.random.default_rng(3)
    sent: dict[str, list[np.ndarray]] = {"upperarm": [], "forearm": []}
    batch = []
    per_message = 300  # two messages a block: a third would pass its 819 rows
    for seq in range(8):
        sensor = "upperarm" if seq % 4 else "forearm"
        rows = rng.normal(size=(per_message, 10))
        rows[:, 0] = seq + np.arange(per_message) * 1e-3
        sent[sensor].append(rows)
        batch.append(Write(state, seq, samples=Samples(seq, sensor, rows)))

    async def commit() -> None:
        writer = GroupWriter(engine, 0.01)
        writer.start()
        for write in batch:
            writer.submit(write)
        await state.idle.wait()
        await writer.stop()

    asyncio.run(commit())
    assert BLOCK_MAX_ROWS == STORED_MAX_BYTES // 80 == 819
    with engine.connect() as connection:
        blocks = connection.execute(
            select(models.SampleBlock.sensor, models.SampleBlock.ordinal,
                   models.SampleBlock.n_rows, models.SampleBlock.t_first,
                   models.SampleBlock.t_last, models.SampleBlock.data)
            .order_by(models.SampleBlock.sensor, models.SampleBlock.ordinal)).all()
    # forearm: seqs 0 and 4 (one block); upperarm: 1 2 | 3 5 | 6 7
    assert [(b.sensor, b.ordinal, b.n_rows) for b in blocks] == [
        ("forearm", 0, 600), ("upperarm", 1, 600), ("upperarm", 3, 600),
        ("upperarm", 6, 600)]
    for sensor in sent:
        mine = [b for b in blocks if b.sensor == sensor]
        stored = np.concatenate([unpack(b.data, 10) for b in mine])
        assert stored.tobytes() == np.concatenate(sent[sensor]).tobytes()
        for b in mine:
            assert b.data[:2] == b"\x78\x01"  # stored, not compressed
            assert (b.t_first, b.t_last) == (unpack(b.data, 10)[0, 0],
                                             unpack(b.data, 10)[-1, 0])
    assert state.durable_seq == 7
    engine.dispose()
