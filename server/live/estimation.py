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
list of outcomes: a pose (a dict ready to publish), None, or a ``LiveFailure``. If the
process dies, the estimators it held answer with a ``LiveFailure`` (their streams go on,
stored as ever, without live poses) and a new process takes the next streams.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import signal
import threading
import traceback
from collections import deque
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any, Protocol

import numpy as np
from armtrack.estimator.pipeline import PipelineConfig

from .. import heap
from ..ingest.protocol import ROW_WIDTH, MarkMessage, Samples
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


#: What an estimator returns for a job: a pose, nothing new, or why it stopped.
Outcome = dict[str, Any] | LiveFailure | None


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
                                                opening.max_rate_hz)
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
        await asyncio.gather(*(asyncio.get_running_loop().run_in_executor(None, child.stop)
                               for child in self._children))

    async def run(self, jobs: list[Job], closed: list[int]) -> list[tuple[int, Outcome]]:
        n = len(self._children)
        loop = asyncio.get_running_loop()
        sent = []
        for i, child in enumerate(self._children):
            share = [job for job in jobs if job[0] % n == i]
            gone = [key for key in closed if key % n == i]
            if share or gone:  # sent in order: each child's sends are on its one thread
                sent.append(loop.run_in_executor(child.executor, child.submit, share, gone))
        futures = await asyncio.gather(*sent)
        results = await asyncio.gather(*(asyncio.wrap_future(f) for f in futures))
        return [outcome for share in results for outcome in share]


class EstimationProcess:
    """One child process holding estimators, and the pipe to it. Batches are sent on
    their own thread (``executor``: a big batch fills the pipe until the child reads it)
    and their outcomes read on another, in the order sent, so a batch can be sent while
    the one before is still computed."""

    def __init__(self, index: int):
        self.index = index
        self.executor = ThreadPoolExecutor(1, thread_name_prefix=f"armtrack-live-pipe{index}")
        self._lock = threading.Lock()
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        #: batches sent and not answered yet, oldest first: (future, keys of their jobs)
        self._waiting: deque[tuple[Future, list[int]]] = deque()

    def start(self) -> None:
        with self._lock:
            if self._process is None:
                self._spawn()

    def _spawn(self) -> None:
        context = multiprocessing.get_context("spawn")  # no copy of this process's threads
        ours, theirs = context.Pipe()
        process = context.Process(target=serve, args=(theirs,), daemon=True,
                                  name=f"armtrack-live-{self.index}")
        process.start()
        theirs.close()
        self._process, self._conn = process, ours
        self._waiting = deque()
        threading.Thread(target=self._read, args=(process, ours, self._waiting),
                         name=f"armtrack-live-read{self.index}", daemon=True).start()

    def submit(self, jobs: list[Job], closed: list[int]) -> Future:
        """Send a batch (on ``executor``); the future gets its outcomes."""
        future: Future = Future()
        with self._lock:
            if self._process is None:
                self._spawn()
            assert self._conn is not None
            self._waiting.append((future, [key for key, _, _ in jobs]))
            try:
                self._conn.send((jobs, closed))
            except OSError:  # the process died: its reader answers every waiting batch
                pass
        return future

    def _read(self, process: multiprocessing.process.BaseProcess, conn: Connection,
              waiting: deque[tuple[Future, list[int]]]) -> None:
        """The outcomes of each batch, in the order sent, until the process ends."""
        while True:
            try:
                outcomes = conn.recv()
            except (EOFError, OSError):
                break
            future, _ = waiting.popleft()
            future.set_result(outcomes)
        with self._lock:  # the process died (killed, out of memory) or was stopped
            stopping = self._process is not process
            if not stopping:
                self._process = self._conn = None
            conn.close()
            process.join(1.0)
            reason = f"the live estimation process stopped (exit code {process.exitcode})"
            if waiting and not stopping:
                log.error("%s; a new one takes the next streams", reason)
            while waiting:
                future, keys = waiting.popleft()
                future.set_result([(key, LiveFailure(reason, reason)) for key in keys])

    def stop(self) -> None:
        self.executor.shutdown(wait=True)  # nothing more is sent
        with self._lock:
            process, conn = self._process, self._conn
            self._process = self._conn = None
        if process is not None and conn is not None:
            with contextlib.suppress(OSError):
                conn.send(None)  # ends its loop; the reader sees the pipe close
            process.join(STOP_TIMEOUT_S)
            if process.is_alive():
                process.terminate()
                process.join(STOP_TIMEOUT_S)


def serve(conn: Connection) -> None:
    """The live estimation process: batches in, outcomes out, until told to stop (None)
    or the server is gone (the pipe closes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl+C stops the server; it stops us
    heap.settle()
    estimators: dict[int, LiveEstimator] = {}
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        jobs, closed = message
        conn.send(run_jobs(estimators, jobs, closed))
