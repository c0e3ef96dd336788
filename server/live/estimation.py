"""Where the live estimates are computed. The streams' ``LiveEstimator``s live, by key, in
the live estimation process (``ARMTRACK_LIVE_PROCESSES``, 1 by default; keys shared out
over several), or, with 0, on a thread pool of the server process.

Why a process: the estimators' work is Python calls around compiled kernels, so threads
of the server process hold its one interpreter lock while they run, and every pose
computed is time the event loop cannot spend on the kits' messages. In its own process
that work runs on another core: on this 2-core machine the server took 74 % of its core
for 150 patients with the estimators on threads (``bench/ingest.py``, README "Load").

A batch goes to the process as one message — per estimator its key, its ``Opening`` the
first time, and its new messages; the keys of closed streams — and comes back as one
list of outcomes: a pose (``EncodedPose``: its JSON, ready to publish), None, or a
``LiveFailure``. If the process dies, the estimators it held answer with a
``LiveFailure`` (their streams go on, stored as ever, without live poses) and a new
process takes the next streams.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import os
import pickle
import struct
import traceback
from collections import deque
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Protocol

import numpy as np
from armtrack.estimator.pipeline import PipelineConfig
from armtrack.estimator.recording.points import PointsFrame

from .. import heap
from ..ingest.protocol import ROW_WIDTH, MarkMessage, Samples
from ..processes import (
    LIVE_ESTIMATION,
    become_child,
    end_child,
    exit_child,
    requests,
    spawn_child,
)
from .encoded import EncodedPose
from .estimator import LiveEstimator

log = logging.getLogger("armtrack.live")

#: Seconds a live estimation process is given to end by itself at shutdown.
STOP_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Opening:
    """What makes a stream's estimator: its pipeline's config, its session, and the most
    poses it returns per second."""

    config: PipelineConfig
    session_id: int
    max_rate_hz: float
    #: the stream's wrist points' frame (docs/extensions/points.md), or None
    points_frame: PointsFrame | None = None
    #: the kit's remembered gyroscope biases the filters start from (sensor → [rad/s],
    #: docs/gyro-bias-memory.md), or None
    gyr_bias_priors: Mapping[str, tuple[float, float, float]] | None = None
    #: the clinic's time zone (``ARMTRACK_CLINIC_TIMEZONE``): the clock of the estimator's
    #: words ("the hand sensor stopped sending at 12:03")
    clinic_timezone: str = "UTC"


@dataclass(frozen=True)
class LiveFailure:
    """An estimator that stopped: ``reason`` for the therapist, ``details`` for the log."""

    reason: str
    details: str


#: A message as it travels to the estimators: (sensor, the rows' float64 bytes) for
#: samples, (t, label) for a mark. Plain tuples pickle ~25× faster than the records with
#: their arrays (a batch of 60 streams × 3 messages: 19 µs against 550 µs).
WireItem = tuple[str, bytes] | tuple[float, str]
#: One estimator's part of a batch: (key, its opening the first time or None, messages).
Job = tuple[int, Opening | None, list[WireItem]]


def to_wire(items: Sequence[Samples | MarkMessage]) -> list[WireItem]:
    """Accepted messages as they travel to the estimators."""
    return [(item.sensor, item.rows.tobytes()) if isinstance(item, Samples)
            else (item.t, item.label) for item in items]


def from_wire(items: Sequence[WireItem]) -> list[Samples | MarkMessage]:
    """The messages again, for ``LiveEstimator.process`` (their ``seq`` is not needed
    there and does not travel: -1)."""
    out: list[Samples | MarkMessage] = []
    for first, second in items:
        if isinstance(first, str):
            rows = np.frombuffer(second, dtype=np.float64).reshape(-1, ROW_WIDTH)
            out.append(Samples(-1, first, rows))
        else:
            out.append(MarkMessage(-1, first, second))
    return out


#: What an estimator returns for a job: a pose, nothing new, ``HELD`` (a pose waits for
#: the pose rate: ask again after it), or why it stopped.
Outcome = EncodedPose | LiveFailure | str | None


def run_jobs(estimators: dict[int, LiveEstimator], jobs: Sequence[Job],
             closed: Sequence[int]) -> list[tuple[int, Outcome]]:
    """Let the ``closed`` keys go, then run each job on its estimator (made from its
    opening). One estimator's failure is its own: it is returned, not raised."""
    for key in closed:
        estimators.pop(key, None)
    outcomes: list[tuple[int, Outcome]] = []
    for key, opening, items in jobs:
        outcome: Outcome
        try:
            if opening is not None:
                estimators[key] = LiveEstimator(opening.config, opening.session_id,
                                                opening.max_rate_hz, opening.points_frame,
                                                opening.gyr_bias_priors,
                                                opening.clinic_timezone)
            estimator = estimators.get(key)
            if estimator is None:
                outcome = LiveFailure("the live estimation process stopped (a new one "
                                      "does not hold this stream's estimator)",
                                      f"no live estimator {key}")
            else:
                outcome = estimator.process(from_wire(items))
        except Exception as exc:
            estimators.pop(key, None)
            outcome = LiveFailure(f"{type(exc).__name__}: {exc}", traceback.format_exc())
        outcomes.append((key, outcome))
    return outcomes


class Estimation(Protocol):
    """Runs a batch of jobs where the estimators live; up to ``depth`` batches at once,
    each key's jobs in the order of the batches."""

    depth: int

    async def start(self) -> None: ...

    async def stop(self) -> None: ...

    async def run(self, jobs: list[Job], closed: list[int]) -> list[tuple[int, Outcome]]: ...


def make_estimation(processes: int, threads: int) -> Estimation:
    """``processes`` live estimation processes, or with 0 ``threads`` threads here."""
    if processes > 0:
        return ProcessEstimation(processes)
    return ThreadEstimation(threads)


class ThreadEstimation:
    """The estimators in this process, run on a thread pool (jobs shared out by key)."""

    #: batches that may be under way at once (one: a key's estimator is on one thread)
    depth = 1

    def __init__(self, threads: int):
        self._threads = max(1, threads)
        self._executor = ThreadPoolExecutor(self._threads, thread_name_prefix="armtrack-live")
        self._estimators: dict[int, LiveEstimator] = {}  # each key on one thread a batch

    async def start(self) -> None:
        """Nothing to start: the pool makes its threads when first used."""

    async def stop(self) -> None:
        self._executor.shutdown(wait=True)

    async def run(self, jobs: list[Job], closed: list[int]) -> list[tuple[int, Outcome]]:
        loop = asyncio.get_running_loop()
        for key in closed:
            self._estimators.pop(key, None)
        shares = [jobs[i::self._threads] for i in range(self._threads)]
        results = await asyncio.gather(*(
            loop.run_in_executor(self._executor, run_jobs, self._estimators, share, ())
            for share in shares if share))
        return [outcome for share in results for outcome in share]


class ProcessEstimation:
    """The estimators in ``processes`` child processes, keys shared out by ``key % n``."""

    #: batches that may be under way at once: the next is sent while one is computed (a
    #: child takes them in order)
    depth = 2

    def __init__(self, processes: int):
        self._children = [EstimationProcess(i) for i in range(processes)]

    async def start(self) -> None:
        for child in self._children:
            child.start()

    async def stop(self) -> None:
        await asyncio.gather(*(child.stop() for child in self._children))

    async def run(self, jobs: list[Job], closed: list[int]) -> list[tuple[int, Outcome]]:
        n = len(self._children)
        sent = []
        for i, child in enumerate(self._children):
            share = [job for job in jobs if job[0] % n == i]
            gone = [key for key in closed if key % n == i]
            if share or gone:
                sent.append(child.submit(share, gone))
        results = await asyncio.gather(*sent)
        return [outcome for share in results for outcome in share]


#: A frame of ``multiprocessing.Connection`` (Unix): the payload's length, 4 bytes
#: big-endian signed, then the payload (-1 and 8 bytes for one of 2 GiB or more).
_FRAME = struct.Struct("!i")
_LONG_FRAME = struct.Struct("!Q")
#: Most bytes read from a child's pipe at once.
_READ_BYTES = 1 << 20


class EstimationProcess:
    """One child process holding estimators, and the pipe to it, read and written by the
    event loop itself: no thread of ours touches it. (Threads did before; each of their
    wake-ups waited for the interpreter lock, which the busy loop gives up only every
    switch interval, 5 ms, several times a batch: at 200 patients a third of the batches
    took over 20 ms there and back, 31 ms at their median, for a median 4 ms of
    computing.) Batches are written as the frames
    of ``multiprocessing.Connection``, which the child reads with ``recv``; its outcomes
    are read as they come, in the order the batches were sent."""

    def __init__(self, index: int):
        self.index = index
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None  # our end (owns the non-blocking fd)
        self._out = bytearray()  # framed batches not written yet
        self._in = bytearray()  # bytes read, not yet a whole frame
        self._writing = False  # waiting for the pipe to take more
        #: batches sent and not answered yet, oldest first: (future, keys of their jobs)
        self._waiting: deque[tuple[asyncio.Future, list[int]]] = deque()
        self._given_work = False  # a batch was sent to the current child

    def start(self) -> None:
        """Start the child (on the event loop)."""
        if self._process is None:
            self._spawn()

    def _spawn(self) -> None:
        process, ours = spawn_child(serve, name=f"armtrack-live-{self.index}")
        os.set_blocking(ours.fileno(), False)
        self._process, self._conn = process, ours
        self._given_work = False  # no batch sent to this child yet
        self._out, self._in, self._writing = bytearray(), bytearray(), False
        self._waiting = deque()
        asyncio.get_running_loop().add_reader(ours.fileno(), self._readable, process)

    def submit(self, jobs: list[Job], closed: list[int]) -> asyncio.Future:
        """Send a batch; the future gets its outcomes (on the event loop)."""
        if self._process is None:
            self._spawn()
        self._given_work = True
        future = asyncio.get_running_loop().create_future()
        self._waiting.append((future, [key for key, _, _ in jobs]))
        payload = pickle.dumps((jobs, closed), pickle.HIGHEST_PROTOCOL)
        if len(payload) < 0x7FFFFFFF:
            self._out += _FRAME.pack(len(payload))
        else:  # pragma: no cover - a batch of gigabytes
            self._out += _FRAME.pack(-1) + _LONG_FRAME.pack(len(payload))
        self._out += payload
        self._write()
        return future

    def _write(self) -> None:
        """As much of ``_out`` as the pipe takes now; the rest when it is writable."""
        if self._conn is None:
            return
        fd = self._conn.fileno()
        try:
            written = os.write(fd, self._out) if self._out else 0
        except BlockingIOError:
            written = 0
        except OSError:  # the child is gone: the reader sees the pipe close
            self._out.clear()
            written = 0
        del self._out[:written]
        loop = asyncio.get_running_loop()
        if self._out and not self._writing:
            loop.add_writer(fd, self._write)
            self._writing = True
        elif not self._out and self._writing:
            loop.remove_writer(fd)
            self._writing = False

    def _readable(self, process: multiprocessing.process.BaseProcess) -> None:
        """What the child wrote: each whole frame is the outcomes of the oldest batch."""
        if self._process is not process or self._conn is None:
            return
        buffer, fd = self._in, self._conn.fileno()
        while True:  # all there is now, in this one turn of the loop
            try:
                data = os.read(fd, _READ_BYTES)
            except BlockingIOError:
                break
            except OSError:
                data = b""
            if not data:  # the process died (killed, out of memory)
                self._lost(process)
                return
            buffer += data
            if len(data) < _READ_BYTES:
                break
        while len(buffer) >= _FRAME.size:
            (size,) = _FRAME.unpack_from(buffer)
            head = _FRAME.size
            if size == -1:  # pragma: no cover - outcomes of gigabytes
                if len(buffer) < head + _LONG_FRAME.size:
                    break
                (size,) = _LONG_FRAME.unpack_from(buffer, head)
                head += _LONG_FRAME.size
            if len(buffer) < head + size:
                break
            outcomes = pickle.loads(bytes(buffer[head:head + size]))
            del buffer[:head + size]
            future, _ = self._waiting.popleft()
            if not future.done():
                future.set_result(outcomes)

    def _detach(self) -> tuple[multiprocessing.process.BaseProcess | None, Connection | None]:
        """Stop watching the pipe; the process and our end, now no longer ours."""
        process, conn = self._process, self._conn
        self._process = self._conn = None
        if conn is not None:
            loop = asyncio.get_running_loop()
            loop.remove_reader(conn.fileno())
            if self._writing:
                loop.remove_writer(conn.fileno())
                self._writing = False
        return process, conn

    def _lost(self, process: multiprocessing.process.BaseProcess) -> None:
        """The child died: every batch waiting gets a failure for each of its keys (their
        streams go on without live poses); the next batch starts a new child."""
        _, conn = self._detach()
        if conn is not None:
            conn.close()
        waiting, self._waiting = self._waiting, deque()

        def answer(_: object = None) -> None:
            reason = f"the live estimation process stopped (exit code {process.exitcode})"
            if waiting:
                log.error("%s; a new one takes the next streams", reason)
            for future, keys in waiting:
                if not future.done():
                    future.set_result([(key, LiveFailure(reason, reason)) for key in keys])

        # its exit code, without holding the loop while it is reaped
        asyncio.get_running_loop().run_in_executor(None, process.join, 1.0
                                                   ).add_done_callback(answer)

    async def stop(self) -> None:
        process, conn = self._detach()
        for future, keys in self._waiting:
            if not future.done():
                future.set_result([(key, LiveFailure("the server is stopping", "stopped"))
                                   for key in keys])
        self._waiting = deque()
        if process is None or conn is None:
            return

        given_work = self._given_work

        def end() -> None:
            os.set_blocking(conn.fileno(), True)
            end_child(process, conn, STOP_TIMEOUT_S, given_work=given_work)

        await asyncio.get_running_loop().run_in_executor(None, end)


def serve(conn: Connection) -> None:
    """The live estimation process: batches in, outcomes out, until told to stop (None)
    or the server is gone (the pipe closes); then it ends at once (``processes.exit_child``)."""
    become_child(LIVE_ESTIMATION)
    heap.settle()
    estimators: dict[int, LiveEstimator] = {}
    for jobs, closed in requests(conn):
        conn.send(run_jobs(estimators, jobs, closed))
    exit_child()
