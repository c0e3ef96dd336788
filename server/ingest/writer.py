"""Group commit: messages accepted from every stream are stored together, a few times a
second, in one transaction; only then are they acked. One commit per batch keeps SQLite's
fsync cost per message small, and the database work runs on its own thread, never on
the event loop. On PostgreSQL the sample blocks go in with ``COPY`` (binary): about twice
as fast as the executemany insert (``bench/pg_storage.py``). On SQLite the statements go
to the driver as plain SQL over tuples (``exec_driver_sql``): SQLAlchemy's per-row
parameter processing was a quarter of a commit's time (a commit of 150 streams × 3
messages: 8.6 → 6.6 ms; with the small blocks left uncompressed, ``store.blocks``, it was
17.4 ms).

On SQLite each statement also goes over many rows at once (multi-row ``VALUES``, ``UPDATE
… FROM (VALUES …)``, one ``json_group_object`` row for the fence), never one execution per
row: the driver lets go of the interpreter lock around every execution step, and with the
event loop busy on another thread each step waits up to the switch interval (5 ms) to get
it back. 1,000 rows inserted by ``executemany`` (the bare driver, one table) took 6–9 s
beside a busy thread (5 ms alone); as two multi-row statements, 24 ms. In the server at
200 patients, commits of ~1,100 messages took 78 ms (p50) to 1.6 s, and a kit's ack
waited for them.

Fencing (several server instances on one database, README "Scaling out"): a stream's
messages are stored only if the stream's stored ``next_seq`` is, in the same transaction
(its row locked on PostgreSQL), the first ``seq`` being stored. If another instance took
the stream over (its kit resumed there) and stored anything, the stream is *fenced* here:
its writes are dropped, unstored and unacked, and its connection is closed
(``on_fenced``), so the kit resumes from what the database holds. Every ``seq`` of a
stream is thus stored once and in order, whichever instances stored it. The same check
reads the stream's session (locked with it on PostgreSQL, so a close on another instance
and this commit are one before the other): a session closed meanwhile — its estimate
begun without what follows — takes nothing more; the stream is fenced as ``closed``, its
writes unacked, and its connection ends as a close on this instance would have ended it
(the kit's resume is told the session is closed, and its ``next_seq``)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import chain

import numpy as np
import orjson
from sqlalchemy import Connection, Engine, bindparam, case, insert, select, update

from ..db import models
from ..db.errors import database_words
from ..store.blocks import STORED_MAX_BYTES, pack_stored
from .protocol import ROW_WIDTH, MarkMessage, Samples, dumps

log = logging.getLogger("armtrack.ingest")

#: Most accepted-but-unstored messages before a stream stops reading (back-pressure).
MAX_PENDING_PER_STREAM = 2000
#: Most rows in one stored block of a stream (its messages of one commit, one sensor):
#: as many as are stored uncompressed (``store.blocks.pack_stored``); a longer message is
#: a block of its own.
BLOCK_MAX_ROWS = STORED_MAX_BYTES // (8 * ROW_WIDTH)
#: Retry delay after a failed commit [s].
RETRY_S = 0.5
#: Keys of a stream's stored ``last_t`` that are not sensors: a stream continuing a session
#: (hello ``session``) keeps its clock offset [s] and the first block ordinal it uses.
T_OFFSET_KEY = "~t_offset"
ORDINAL_BASE_KEY = "~ordinal_base"
#: ``last_t`` key prefix of when a sensor's last rows were stored [s, Unix time], e.g.
#: ``~seen:forearm``: the sensor table's "last seen" of a stream no page watched, true for
#: a backlog sent later (and faster) than it was recorded (``api/live_status.py``).
SEEN_PREFIX = "~seen:"
#: ``last_t`` key of when the stream's connection was lost without a ``bye`` [s, Unix
#: time]: the kit was heard until then, data or not (``store/silence.py``).
HEARD_KEY = "~heard"

_STREAMS = models.Stream.__table__
_SESSIONS = models.Session.__table__
_INSERT_BLOCKS = insert(models.SampleBlock.__table__)
_INSERT_MARKS = insert(models.Mark.__table__)
_UPDATE_STREAM = (update(_STREAMS).where(_STREAMS.c.id == bindparam("stream"))
                  .values(next_seq=bindparam("next_seq"), last_t=bindparam("last_t")))
_ADD_SAMPLES = (update(_SESSIONS).where(_SESSIONS.c.id == bindparam("session"))
                .values(samples=_SESSIONS.c.samples + bindparam("n"),
                        # live again if an instance the stream left marked it interrupted
                        status=case((_SESSIONS.c.status == "interrupted", "live"),
                                    else_=_SESSIONS.c.status)))
_BLOCK_COLUMNS = ("session_id", "sensor", "ordinal", "n_rows", "t_first", "t_last", "data")
_COPY_BLOCKS = f"COPY sample_blocks ({', '.join(_BLOCK_COLUMNS)}) FROM STDIN (FORMAT BINARY)"
_COPY_TYPES = ["int4", "varchar", "int8", "int4", "float8", "float8", "bytea"]
# the same statements as plain SQL for SQLite's driver (qmark parameters), each over many
# rows: ``_sqlite_many`` puts a row's ``(?, …)`` in for every ``{rows}``
_SQLITE_INSERT_BLOCKS = (f"INSERT INTO sample_blocks ({', '.join(_BLOCK_COLUMNS)}) "
                         "VALUES {rows}")
_SQLITE_INSERT_MARKS = "INSERT INTO marks (session_id, t, label) VALUES {rows}"
_SQLITE_UPDATE_STREAMS = ("UPDATE streams SET next_seq = v.column1, last_t = v.column2 "
                          "FROM (VALUES {rows}) AS v WHERE streams.id = v.column3")
_SQLITE_ADD_SAMPLES = ("UPDATE sessions SET samples = samples + v.column1, status = CASE "
                       "WHEN status = 'interrupted' THEN 'live' ELSE status END "
                       "FROM (VALUES {rows}) AS v WHERE sessions.id = v.column2")
_SQLITE_STORED_SEQS = ("SELECT json_group_object(streams.id, json_array(streams.next_seq, "
                       "sessions.status)) FROM streams JOIN sessions ON sessions.id = "
                       "streams.session_id WHERE streams.id IN ({rows})")
#: Rows in one SQLite statement (its parameters stay far below SQLite's 32,766).
SQLITE_ROWS_PER_STATEMENT = 500


@dataclass(eq=False)
class StreamState:
    """What the ingest side knows of one stream: ``next_seq`` accepted in memory,
    ``durable_seq`` stored (the ack), the last sample time per sensor (and, for a stream
    continuing a session, its clock offset and first block ordinal, under
    :data:`T_OFFSET_KEY` and :data:`ORDINAL_BASE_KEY`)."""

    stream_id: str
    session_id: int
    next_seq: int
    last_t: dict[str, float]
    stored_last_t: dict[str, float] = field(default_factory=dict)
    durable_seq: int = -1
    pending: int = 0
    on_durable: Callable[[], None] = lambda: None
    on_storage_error: Callable[[str], None] = lambda reason: None
    #: another instance stores this stream now (``"taken"``), or its session was closed
    #: (``"closed"``; see the module's "Fencing")
    on_fenced: Callable[[str], None] = lambda why: None
    fenced: bool = False
    idle: asyncio.Event = field(default_factory=asyncio.Event)
    t_offset: float = 0.0
    ordinal_base: int = 0

    def __post_init__(self) -> None:
        self.durable_seq = self.next_seq - 1
        self.stored_last_t = dict(self.last_t)
        self.t_offset = float(self.last_t.get(T_OFFSET_KEY, 0.0))
        self.ordinal_base = int(self.last_t.get(ORDINAL_BASE_KEY, 0))
        self.idle.set()


@dataclass(slots=True)
class Write:
    """One handled message: stored data (samples or a mark) or a refused ``seq`` that
    only moves the stream's count on."""

    stream: StreamState
    seq: int
    samples: Samples | None = None
    mark: MarkMessage | None = None


class GroupWriter:
    """Collects writes from all streams and commits them in batches."""

    def __init__(self, engine: Engine, interval_s: float):
        self._engine = engine
        self._interval = interval_s
        self._queue: list[Write] = []
        self._wake = asyncio.Event()
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="armtrack-writer")
        self._task: asyncio.Task | None = None
        self.commits = 0
        self.failures = 0
        #: while commits fail: since when [s, Unix time] and what the database said
        #: (``/healthz`` and the live views say it); None once a commit succeeds
        self.failing: dict[str, float | str] | None = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="armtrack-group-writer")

    async def stop(self) -> None:
        """Store what is queued, then stop."""
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        while self._queue:
            batch, self._queue = self._queue, []
            try:
                fenced = await asyncio.get_running_loop().run_in_executor(
                    self._executor, self._commit, batch)
                self._done(batch, fenced)
            except Exception:  # the data stay unacked: the kit resends after a restart
                log.exception("final commit failed")
                break
        self._executor.shutdown(wait=True)

    def submit(self, write: Write) -> None:
        write.stream.pending += 1
        write.stream.idle.clear()
        self._queue.append(write)
        self._wake.set()

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            await asyncio.sleep(self._interval)  # let a batch gather
            self._wake.clear()
            batch, self._queue = self._queue, []
            if not batch:
                continue
            try:
                fenced = await loop.run_in_executor(self._executor, self._commit, batch)
            except Exception as exc:
                self.failures += 1
                words = database_words(exc)
                if self.failing is None:
                    self.failing = {"since": time.time(), "reason": words}
                log.warning("commit of %d messages failed: %s", len(batch), exc)
                for stream in {w.stream for w in batch}:
                    # the database's words stay out: kits match reasons' words
                    # (kit-stream.js), and the operator reads them in the log
                    stream.on_storage_error("storage failed: the server cannot store data "
                                            "now; the data stay unacked and will be retried")
                self._queue[:0] = batch
                await asyncio.sleep(RETRY_S)
                self._wake.set()
                continue
            self.commits += 1
            if self.failing is not None:
                log.warning("commits succeed again after failing since %s",
                            time.strftime("%H:%M:%S", time.localtime(self.failing["since"])))
                self.failing = None
            self._done(batch, fenced)

    def _done(self, batch: list[Write], fenced: dict[str, str] | None = None) -> None:
        fenced = fenced or {}
        for write in batch:
            stream = write.stream
            stream.pending -= 1
            if stream.stream_id not in fenced:
                stream.durable_seq = max(stream.durable_seq, write.seq)
        for stream in {w.stream for w in batch}:
            if stream.pending == 0:
                stream.idle.set()
            if stream.stream_id in fenced:
                if not stream.fenced:
                    stream.fenced = True
                    why = fenced[stream.stream_id]
                    log.warning("stream %s fenced off here: %s", stream.stream_id,
                                "its session was closed" if why == "closed"
                                else "it goes on on another instance")
                    stream.on_fenced(why)
            else:
                stream.on_durable()

    def _commit(self, batch: list[Write]) -> dict[str, str]:
        """One transaction: the streams' stored positions and sessions checked (fencing),
        then ``_store``; returns the streams fenced off (nothing of theirs stored), each
        with why: ``"taken"`` or ``"closed"``."""
        with self._engine.begin() as connection:
            fenced = _fence(connection, batch)
            if fenced:
                batch = [w for w in batch if w.stream.stream_id not in fenced]
            stored = self._store(connection, batch) if batch else []
        for stream, last_t in stored:  # once committed
            stream.stored_last_t = last_t
        return fenced

    def _store(self, connection: Connection, batch: list[Write]
               ) -> list[tuple[StreamState, dict[str, float]]]:
        """The blocks, the marks, each stream's position and each session's sample count;
        returns each stream's stored last times."""
        marks = []
        # a stream's messages of one sensor in this batch, in seq order: one block
        runs: dict[tuple[str, str], list[tuple[int, np.ndarray]]] = {}
        streams: dict[str, tuple[StreamState, int]] = {}
        last_t: dict[str, dict[str, float]] = {}
        counts: dict[int, int] = {}
        now = time.time()  # the rows' arrival, to the commit's delay (ack_interval_s)
        for write in batch:
            stream = write.stream
            top = streams.get(stream.stream_id, (stream, -1))[1]
            streams[stream.stream_id] = (stream, max(top, write.seq))
            times = last_t.setdefault(stream.stream_id, dict(stream.stored_last_t))
            if write.samples is not None:
                rows = write.samples.rows
                times[write.samples.sensor] = float(rows[-1, 0])
                times[SEEN_PREFIX + write.samples.sensor] = now
                runs.setdefault((stream.stream_id, write.samples.sensor), []).append(
                    (write.seq, rows))
                counts[stream.session_id] = counts.get(stream.session_id, 0) + len(rows)
            elif write.mark is not None:
                marks.append({"session_id": stream.session_id, "t": write.mark.t,
                              "label": write.mark.label})
        blocks = [block for (stream_id, sensor), run in runs.items()
                  for block in _blocks(streams[stream_id][0], sensor, run)]
        positions = [(top + 1, last_t[stream_id], stream_id)
                     for stream_id, (_, top) in streams.items()]
        sessions = list(counts.items())
        if connection.dialect.name == "sqlite":  # a few statements over many rows each
            _sqlite_many(connection, _SQLITE_INSERT_BLOCKS, blocks)
            _sqlite_many(connection, _SQLITE_INSERT_MARKS, [
                (mark["session_id"], mark["t"], mark["label"]) for mark in marks])
            _sqlite_many(connection, _SQLITE_UPDATE_STREAMS, [
                (seq, dumps(times), stream_id) for seq, times, stream_id in positions])
            _sqlite_many(connection, _SQLITE_ADD_SAMPLES,
                         [(n, session_id) for session_id, n in sessions])
            return [(stream, last_t[stream_id]) for stream_id, (stream, _) in streams.items()]
        # each statement executed once over many parameter sets (no ORM per row)
        if blocks:
            _insert_blocks(connection, blocks)
        if marks:
            connection.execute(_INSERT_MARKS, marks)
        connection.execute(_UPDATE_STREAM, [
            {"stream": stream_id, "next_seq": seq, "last_t": times}
            for seq, times, stream_id in positions])
        if sessions:
            connection.execute(_ADD_SAMPLES, [{"session": session_id, "n": n}
                                              for session_id, n in sessions])
        return [(stream, last_t[stream_id]) for stream_id, (stream, _) in streams.items()]


def _blocks(stream: StreamState, sensor: str, run: list[tuple[int, np.ndarray]]
            ) -> list[tuple]:
    """One sensor's messages of one batch, in seq order, as rows of ``sample_blocks``
    (tuples in the order of ``_BLOCK_COLUMNS``): consecutive messages go in one block of
    up to ``BLOCK_MAX_ROWS`` rows, whose ordinal is its first message's (so a sensor's
    blocks still sort by ordinal, and a stream continuing the session numbers after
    them). Fewer, longer blocks keep the commit small: each block is an entry in the
    ``(session, sensor, ordinal)`` index, whose pages are spread over every live session."""
    blocks: list[tuple] = []
    start = 0
    while start < len(run):
        end, n = start, 0
        while end < len(run) and (end == start or n + len(run[end][1]) <= BLOCK_MAX_ROWS):
            n += len(run[end][1])
            end += 1
        parts = [rows for _, rows in run[start:end]]
        rows = parts[0] if len(parts) == 1 else np.concatenate(parts)
        blocks.append((stream.session_id, sensor, stream.ordinal_base + run[start][0],
                       len(rows), float(rows[0, 0]), float(rows[-1, 0]), pack_stored(rows)))
        start = end
    return blocks


def _fence(connection: Connection, batch: list[Write]) -> dict[str, str]:
    """The streams of ``batch`` not to store: ``"taken"`` when the stored ``next_seq`` is
    not their first ``seq`` here (another instance stored or stores them), ``"closed"``
    when their session is closed. Their rows and their sessions' stay locked to the
    commit (PostgreSQL; SQLite's transaction holds the database)."""
    first: dict[str, int] = {}
    for write in batch:
        sid = write.stream.stream_id
        first[sid] = min(first.get(sid, write.seq), write.seq)
    if connection.dialect.name == "sqlite":  # one result row, not one a stream
        ids = list(first)
        stored: dict[str, int] = {}
        for start in range(0, len(ids), SQLITE_ROWS_PER_STATEMENT):
            part = ids[start:start + SQLITE_ROWS_PER_STATEMENT]
            found = connection.exec_driver_sql(
                _SQLITE_STORED_SEQS.format(rows=", ".join("?" * len(part))),
                tuple(part)).scalar()
            stored.update({sid: tuple(v) for sid, v in orjson.loads(found or "{}").items()})
    else:
        stored = {sid: (seq, status) for sid, seq, status in connection.execute(
            select(_STREAMS.c.id, _STREAMS.c.next_seq, _SESSIONS.c.status)
            .join(_SESSIONS, _SESSIONS.c.id == _STREAMS.c.session_id)
            .where(_STREAMS.c.id.in_(first)).order_by(_STREAMS.c.id)
            .with_for_update(of=[_STREAMS, _SESSIONS])).all()}
    out = {}
    for sid, seq in first.items():
        stored_seq, status = stored.get(sid, (None, None))
        if stored_seq != seq:
            out[sid] = "taken"
        elif status == "closed":
            out[sid] = "closed"
    return out


def _sqlite_many(connection: Connection, statement: str, rows: list[tuple]) -> None:
    """``statement`` executed over ``rows`` (tuples of one length), at most
    ``SQLITE_ROWS_PER_STATEMENT`` rows an execution: its ``{rows}`` becomes their
    ``(?, …), (?, …)``."""
    if not rows:
        return
    one = f"({', '.join('?' * len(rows[0]))})"
    for start in range(0, len(rows), SQLITE_ROWS_PER_STATEMENT):
        part = rows[start:start + SQLITE_ROWS_PER_STATEMENT]
        connection.exec_driver_sql(statement.format(rows=", ".join([one] * len(part))),
                                   tuple(chain.from_iterable(part)))


def _insert_blocks(connection: Connection, blocks: list[tuple]) -> None:
    """``blocks``: tuples in the order of ``_BLOCK_COLUMNS``."""
    if connection.dialect.name == "postgresql" and connection.dialect.driver == "psycopg":
        raw = connection.connection.driver_connection  # the same transaction
        with raw.cursor() as cursor, cursor.copy(_COPY_BLOCKS) as copy:
            copy.set_types(_COPY_TYPES)
            for block in blocks:
                copy.write_row(block)
    else:
        connection.execute(_INSERT_BLOCKS, [dict(zip(_BLOCK_COLUMNS, block, strict=True))
                                            for block in blocks])
