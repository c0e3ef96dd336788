"""Where closed sessions are estimated: in a process of their own beside the server's, at
a lower CPU priority (``ARMTRACK_PROCESSING_PROCESSES``, 1 by default; 0: on threads of
the server process, as always with an in-memory database, which no other process sees).

Why: a session's end runs its whole recording through the estimator and stores the
result (``processing.process_session``; the estimator alone takes 0.3–0.4 s of CPU for a
30-minute session, ``bench/speed.py``, plus reading and writing its blocks). On threads
of the server process that work holds the interpreter lock the event loop needs for
every live stream's messages. In a child process it runs beside the server, its
estimation on a thread that takes only CPU time nothing else wants (``SCHED_IDLE``), so
the live streams are always served first and a report is ready a moment later. (In
``bench/ingest.py`` at 200 patients, with the sessions ending together, the group commit
stalled for up to 1.5 s; most of that was the write lock the estimation held, see
``processing.process_session``. At ``nice`` 10, and still at 19, the first sessions'
processing took 20–50 % of a core from the live streams for a second and a half: the
pose latency p99 of a run was 118–184 ms, all of it in that second and a half; with the
estimation at ``SCHED_IDLE``, 23–52 ms in the runs right after.)

While streams are live, the child also rests after each session for 3× the time it
took (``ARMTRACK_PROCESSING_SHARE_LIVE``, 0.25: it works a quarter of the time at most)
before the next queued one: idle CPU time is not free on a 2-core machine (the cores'
shared caches, and two hyperthreads of one core). At 250 patients ending their sessions
within 5 s, back-to-back jobs took ~45 % of a core and put 1,500 poses over 100 ms in
the second after the first ``bye``; resting, none (``bench/ingest.py``). A session closed
when nothing streams is estimated at once; one closed beside live streams waits only for
the sessions queued before it.

Jobs go to the child one at a time over a pipe, in the order given; each answers with
None or why it failed. If the child dies (killed, out of memory) the job under way fails
(logged: ``armtrack reprocess SESSION_ID`` redoes it) and a new child takes the next. The
child ends when the server's end of the pipe closes, also when the server is killed.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from sqlalchemy.engine import make_url

from ..processes import (
    PROCESSING,
    become_child,
    end_child,
    exit_child,
    requests,
    spawn_child,
)

log = logging.getLogger("armtrack.processing")

#: How much less CPU priority the processing child has than the server (``nice``; its
#: estimation thread is at ``SCHED_IDLE`` besides, see ``_only_idle_cpu``).
NICENESS = 19
#: Longest rest of the child between two jobs while streams are live [s].
MAX_REST_S = 5.0
#: Seconds the child is given to finish its job and end at shutdown.
STOP_TIMEOUT_S = 30.0


class ProcessingFailed(RuntimeError):
    """A session's processing did not complete; the message says why."""


def shared_with_other_processes(database_url: str) -> bool:
    """Whether another process opens the same database (not SQLite's ``:memory:``)."""
    url = make_url(database_url)
    return not (url.get_backend_name() == "sqlite"
                and url.database in (None, "", ":memory:"))


class SessionProcessing:
    """Estimates closed sessions in the processing child (or on ``threads`` threads of
    this process when ``processes`` is 0)."""

    def __init__(self, database_url: str, processes: int, threads: int,
                 thread_job: Callable[[int, str], None],
                 busy: Callable[[], bool] = lambda: False,
                 share_while_busy: float = 1.0):
        self._url = database_url
        #: while ``busy()`` (streams are live), the child works this share of the time at
        #: most: after a job of w seconds it rests w × (1/share − 1), up to ``MAX_REST_S``
        self._busy = busy
        self._share = share_while_busy
        self._sent_at = 0.0
        self._rest_until = 0.0  # no job is sent before (time.monotonic())
        self._in_child = processes > 0 and shared_with_other_processes(database_url)
        self._thread_job = thread_job
        self._threads = None if self._in_child else ThreadPoolExecutor(
            max(1, threads), thread_name_prefix="armtrack-compute")
        self._lock = threading.Lock()
        self._queue: deque[tuple[Future, int, str]] = deque()  # not sent yet
        self._under_way: tuple[Future, int, str] | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._given_work = False  # a job was sent to the current child
        self._stopped = False

    def start(self) -> None:
        """Start the child now (its imports take a second or two) rather than at the
        first session's end."""
        if self._in_child:
            with self._lock:
                if self._process is None:
                    self._spawn()

    def submit(self, session_id: int, filter_name: str) -> Future:
        """Estimate session ``session_id`` with ``filter_name``; the future is done when its
        estimates are stored (or raises ``ProcessingFailed``)."""
        if self._threads is not None:
            return self._threads.submit(self._thread_job, session_id, filter_name)
        future: Future = Future()
        with self._lock:
            if self._stopped:
                future.set_exception(ProcessingFailed("the server is stopping"))
                return future
            self._queue.append((future, session_id, filter_name))
            if self._process is None:
                self._spawn()
            self._send_next()
        return future

    def stop(self) -> None:
        """Wait for the jobs given (at most ``STOP_TIMEOUT_S`` for the one under way),
        then end the child."""
        if self._threads is not None:
            self._threads.shutdown(wait=True)
            return
        with self._lock:
            self._stopped = True
            self._rest_until = 0.0  # what is queued goes now
            self._send_next()
            waiting = [job[0] for job in ([self._under_way] if self._under_way else [])
                       + list(self._queue)]
        for future in waiting:
            with contextlib.suppress(Exception):
                future.result(timeout=STOP_TIMEOUT_S)
        with self._lock:
            process, conn = self._process, self._conn
            self._process = self._conn = None
            given_work = self._given_work
        if process is not None and conn is not None:
            end_child(process, conn, STOP_TIMEOUT_S, given_work=given_work)

    # -- the child and the pipe (under ``_lock``) -----------------------------------------
    def _spawn(self) -> None:
        process, ours = spawn_child(serve, self._url, name="armtrack-processing")
        self._process, self._conn = process, ours
        self._given_work = False
        threading.Thread(target=self._read, args=(process, ours), daemon=True,
                         name="armtrack-processing-read").start()

    def _send_next(self) -> None:
        if (self._under_way is not None or not self._queue or self._conn is None
                or time.monotonic() < self._rest_until):
            return
        job = self._queue.popleft()
        if not job[0].set_running_or_notify_cancel():
            self._send_next()
            return
        self._under_way = job
        self._sent_at = time.monotonic()
        self._given_work = True
        try:
            self._conn.send((job[1], job[2]))
        except OSError:  # the child died: its reader fails this job and starts another
            pass

    def _rest_after(self, job_s: float) -> float:
        """How long the child rests after a job of ``job_s`` seconds [s]: only while the
        server is busy with live streams (a session's end then waits a little for its
        report, and the live poses keep their pace), and only if more jobs wait."""
        if self._share >= 1.0 or not self._queue or self._stopped or not self._busy():
            return 0.0
        return min(job_s * (1.0 / self._share - 1.0), MAX_REST_S)

    def _after_rest(self) -> None:
        with self._lock:
            self._send_next()

    def _read(self, process: multiprocessing.process.BaseProcess, conn: Connection) -> None:
        """Each job's answer, until the child ends; then the job under way fails and a
        new child takes what is queued."""
        while True:
            try:
                failure = conn.recv()
            except (EOFError, OSError):
                break
            with self._lock:
                job, self._under_way = self._under_way, None
                rest = self._rest_after(time.monotonic() - self._sent_at)
                self._rest_until = time.monotonic() + rest
                self._send_next()
            if rest > 0:  # (a daemon: a rest never holds the interpreter's exit)
                timer = threading.Timer(rest, self._after_rest)
                timer.daemon = True
                timer.start()
            if job is not None:
                if failure is None:
                    job[0].set_result(None)
                else:
                    log.error("processing of session %s failed: %s", job[1], failure)
                    job[0].set_exception(ProcessingFailed(failure.strip().splitlines()[-1]))
        process.join(1.0)
        with self._lock:
            if self._process is not process:  # stopped on purpose
                return
            self._process = self._conn = None
            job, self._under_way = self._under_way, None
            conn.close()
            if job is not None:
                reason = (f"the processing process stopped (exit code {process.exitcode}) "
                          f"while estimating session {job[1]}; `armtrack reprocess {job[1]}` "
                          "estimates it again")
                log.error("%s", reason)
                job[0].set_exception(ProcessingFailed(reason))
            if self._queue and not self._stopped:
                self._spawn()
                self._send_next()


def serve(conn: Connection, database_url: str) -> None:
    """The processing child: (session id, filter) jobs in, None or a traceback out, one
    at a time, until told to stop (None) or the server is gone (the pipe closes); then it
    ends at once (``processes.exit_child``)."""
    become_child(PROCESSING)
    with contextlib.suppress(OSError):
        os.nice(NICENESS)
    from ..db.engine import make_engine, make_sessionmaker
    from .processing import process_in_background

    factory = make_sessionmaker(make_engine(database_url))
    estimating = ThreadPoolExecutor(1, thread_name_prefix="armtrack-estimate",
                                    initializer=_only_idle_cpu)
    # the compiled kernels built (or loaded from their cache) now, on idle CPU time, not
    # when the first patient streams: on a fresh install that took ~55 s (server/warm.py).
    # A thread of its own, so that a job never waits for it.
    threading.Thread(target=_warm_kernels, daemon=True, name="armtrack-warm").start()

    def compute(work: Callable[..., Any], *args: Any) -> Any:
        return estimating.submit(work, *args).result()

    for session_id, filter_name in requests(conn):
        try:
            process_in_background(factory, session_id, filter_name, compute)
            answer = None
        except Exception:
            answer = traceback.format_exc()
        try:
            conn.send(answer)
        except OSError:
            break
    estimating.shutdown(wait=True)
    exit_child()


def _warm_kernels() -> None:
    """``warm.warm`` on idle CPU time; says in the server's log when the kernels are ready
    (or why they could not be built: the kernels are then built at first use)."""
    _only_idle_cpu()
    from ..warm import warm

    try:
        seconds = warm()
    except Exception:
        log.exception("building the compiled kernels ahead failed; they are built when "
                      "the first session needs them")
        return
    print(f"armtrack: compiled kernels ready ({seconds:.1f} s)", flush=True)


def _only_idle_cpu() -> None:
    """This thread runs only on CPU time nothing else wants (Linux ``SCHED_IDLE``; at
    ``NICENESS`` elsewhere). The estimation thread of the processing child: the database
    reads and the write transaction stay on the child's main thread at ``NICENESS``, so a
    busy server can delay an estimate but never starve a transaction holding SQLite's
    write lock (unprivileged, a thread cannot leave ``SCHED_IDLE`` again). The thread
    takes its Python name in the system too (``top -H``, ``/proc/PID/task``), cut to the
    15 characters Linux keeps: "armtrack-estima", "armtrack-warm"."""
    with contextlib.suppress(OSError):
        Path("/proc/thread-self/comm").write_text(threading.current_thread().name[:15])
    policy = getattr(os, "SCHED_IDLE", None)
    if policy is not None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, policy, os.sched_param(0))
