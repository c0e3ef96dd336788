"""What one running server holds: settings, the database, the group writer, the live hub,
the 3D viewer, the thread pools, and the open streams (for resume and for closing revoked
devices)."""

from __future__ import annotations

import asyncio
import contextvars
import logging
import math
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime
from typing import Any, TypeVar

from armtrack.web.viewer.host import ViewerHost
from sqlalchemy import select, update

from .builds import UNCOUNTED
from .db import models
from .db.engine import make_engine, make_sessionmaker
from .db.errors import NOT_UPGRADED
from .db.migrate import schema_words, upgrade
from .export_turns import FairTurns
from .ingest.budget import KitBudget, SharedBudget, follow_loop
from .ingest.writer import GroupWriter, StreamState
from .kit.daily_samples import KitDay
from .live.access import AccessWatch
from .live.broker import make_hub
from .live.estimation import make_estimation
from .live.slots import FeedSlots
from .live.worker import LiveBatcher, LiveWorker
from .periodic import every
from .settings import Settings
from .store.background import SessionProcessing
from .store.processing import process_in_background

T = TypeVar("T")


#: Seconds a lost stream's live side is kept for its resume (``Services.park_live``).
LIVE_PARK_S = 120.0
#: The most lost streams' live sides kept at once.
MAX_PARKED_LIVE = 64
#: Threads for the async side's CPU work (``Services.run_cpu``).
CPU_THREADS = 2
#: Password checks and hashes at once (``Services.run_password``).
PASSWORD_THREADS = 2
#: Password checks and hashes waiting or under way at once (``Services.run_password``):
#: ~6 s of argon2id on two threads; past it a sign-in is answered at once (``PasswordsBusy``)
PASSWORD_WAITING_MAX = 128
#: Session exports that hold a whole session in memory, at once (``Services.run_export``).
EXPORTS_AT_ONCE = 2
#: /healthz asks the database its schema at most this often [s] (a query), once a table
#: or column was found missing; a database at the schema that lacks one is said so for
#: SCHEMA_SUSPECT_S [s] after the last such error
SCHEMA_CHECK_S = 5.0
SCHEMA_SUSPECT_S = 60.0

log = logging.getLogger("armtrack.server")


class ExportUnwanted(Exception):
    """The one who asked for an export went away while it waited its turn."""


class PasswordsBusy(Exception):
    """``PASSWORD_WAITING_MAX`` password checks are waiting already: try again shortly."""


@dataclass
class ParkedLive:
    """The live side of a stream whose connection was lost: its ``LiveWorker``, its kit
    feedback (``FeedbackRunner``, or None), and the timer that lets them go."""

    worker: LiveWorker
    feedback: Any
    expire: asyncio.TimerHandle
    device_id: int | None = None
    #: the stream's patient's therapist: the holder whose share the side counts in
    therapist_id: int | None = None


class Services:
    def __init__(self, settings: Settings):
        self.settings = settings
        settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
        self.engine = make_engine(settings.resolved_database_url())
        self.db = make_sessionmaker(self.engine)
        self.hub = make_hub(settings.broker_url)  # in-process, or through the broker
        #: the loopback viser server and its one-time viewer grants (web/viewer)
        self.viewer = ViewerHost(self, settings.viewer_port, settings.viewer_grant_s)
        self.writer = GroupWriter(self.engine, settings.ack_interval_s)
        #: (monotonic time [s], words) of the last schema check (``schema_problem``), and
        #: when a table or column was last found missing (None: never)
        self._schema_checked: tuple[float, str | None] = (-math.inf, None)
        self._schema_suspect_at: float | None = None
        #: short database reads and writes of the async side
        self.db_pool = ThreadPoolExecutor(4, thread_name_prefix="armtrack-db")
        #: CPU work of the async side (the kits' feedback recounts): off the event loop,
        #: two at a time
        self.cpu_pool = ThreadPoolExecutor(CPU_THREADS, thread_name_prefix="armtrack-cpu")
        #: exports holding a whole session in memory (CSV, OpenSim, PDF): a few at once
        self.exports = FairTurns(EXPORTS_AT_ONCE)
        #: their threads, as many as run at once: the allocator keeps what a thread freed
        #: in that thread's arena, so exports built on any of the request pool's 40
        #: threads kept memory for as many as had built one
        self.export_pool = ThreadPoolExecutor(EXPORTS_AT_ONCE,
                                              thread_name_prefix="armtrack-export")
        #: therapist id → their exports being made or downloaded (``deps.in_export_turn``)
        self.exports_held: dict[int, int] = {}
        #: password hashing (argon2id: 64 MiB, ~0.1 s each), two at a time however many
        #: sign-ins arrive, in a pool of its own: a flood of sign-ins queues behind itself,
        #: not ahead of the kits' feedback
        self.password_pool = ThreadPoolExecutor(PASSWORD_THREADS,
                                                thread_name_prefix="armtrack-password")
        self._passwords_waiting = 0  # run_password's calls not yet answered
        #: estimation of closed sessions (batch), in the processing process
        self.processing = SessionProcessing(
            settings.resolved_database_url(), settings.processing_processes,
            settings.processing_threads,
            lambda session_id, filter_name: process_in_background(self.db, session_id,
                                                                  filter_name),
            busy=lambda: bool(self.connections),
            share_while_busy=settings.processing_share_live)
        #: live estimation: the streams' pipelines, in batches (server/live/worker.py),
        #: in the live estimation process(es) (server/live/estimation.py)
        self.live_estimation = make_estimation(settings.live_processes,
                                               settings.processing_threads)
        self.live = LiveBatcher(self.live_estimation, settings.live_batch_s)
        self.streams: dict[str, StreamState] = {}
        self.connections: dict[str, Any] = {}  # stream id → open IngestConnection
        self.kit_sockets: dict[int, int] = {}  # device id → its open ingest connections
        #: device id → how fast its messages are read (ingest/budget.py), kept while it
        #: has a socket open or a debt to pay
        self.kit_budgets: dict[int, KitBudget] = {}
        #: how fast all kits' messages are read together, in turns, shared among the
        #: kits' therapists (ingest/budget.py)
        self.ingest_budget = SharedBudget(settings.ingest_messages_per_s,
                                          settings.ingest_rows_per_s)
        #: device id → sample rows its sessions of the last day hold, per session, while
        #: it has a socket open (kit/daily_samples.py; from the database at its first)
        self.kit_samples: dict[int, KitDay] = {}
        #: sessions the therapist is closing: a resume or continuation of one is refused as
        #: closed (a kit reconnecting between its stream's end and the close's commit)
        self.closing: set[int] = set()
        #: stream id → the live side of a stream whose connection was lost, kept for its
        #: resume (``park_live``)
        self.parked_live: dict[str, ParkedLive] = {}
        self.sensor_status: dict[int, dict[str, dict[str, Any]]] = {}  # patient → sensor
        self.background: set[asyncio.Future] = set()
        #: the open live feeds and 3D views, closed once their right is gone (live/access)
        self.access = AccessWatch(self.run_db, settings.demo_mode)
        #: each account's live feeds, 3D views and unused viewer grants (live/slots)
        self.feed_slots = FeedSlots(settings.max_live_feeds_per_user)
        self._access_task: asyncio.Task | None = None
        self._kit_check_task: asyncio.Task | None = None
        self._budget_task: asyncio.Task | None = None

    def schema_problem(self) -> str | None:
        """What is wrong with the database's schema and what to run (``/healthz``), or
        None. Asked of the database (``db.migrate.schema_words``, at most every
        ``SCHEMA_CHECK_S``) only once a request or a kit's write met a table or column not
        there (``schema_suspect``): no query for a healthy server's every probe. A
        database at this armtrack's schema that still lacks one (a damaged or foreign
        file) is said in ``NOT_UPGRADED``'s words for ``SCHEMA_SUSPECT_S`` after the last
        such error. None while it cannot be asked (a lock, a server out of reach)."""
        if self._schema_suspect_at is None:
            return None
        now = time.monotonic()
        if now - self._schema_checked[0] >= SCHEMA_CHECK_S:
            try:
                found = schema_words(self.engine)
            except Exception as exc:  # not this check's to say: the writer's failure is
                log.debug("schema check: %s", exc)
                found = None
            self._schema_checked = (now, found)
        found = self._schema_checked[1]
        if found is None and now - self._schema_suspect_at < SCHEMA_SUSPECT_S:
            return NOT_UPGRADED.removeprefix("its ")
        if found is None:
            self._schema_suspect_at = None
        return found

    def schema_suspect(self) -> None:
        """A request or a kit's write met a table or column not there: ``schema_problem``
        asks the database (again, not its answer of up to ``SCHEMA_CHECK_S`` ago)."""
        self._schema_suspect_at = time.monotonic()
        self._schema_checked = (-math.inf, None)

    def migrate(self) -> None:
        """Bring the schema to the newest version, and mark sessions left live by a
        previous run as interrupted (their kits may resume them)."""
        upgrade(self.engine)
        with self.db() as db, db.begin():
            db.execute(update(models.Session).where(models.Session.status == "live")
                       .values(status="interrupted"))

    async def start(self) -> None:
        self.processing.start()
        await self.hub.start()
        self.writer.start()
        await self.live_estimation.start()
        self.live.start()
        await self.viewer.start()
        self._access_task = asyncio.create_task(
            self.access.run(self.settings.access_check_s), name="armtrack-access-check")
        self._kit_check_task = asyncio.create_task(
            self._check_kits(self.settings.access_check_s), name="armtrack-kit-check")
        # all kits together are read at least as fast as one kit may be: a lone kit is
        # never slowed by the others' budget, however busy the loop
        settings = self.settings
        share_min = min(1.0, max(settings.kit_messages_per_s / settings.ingest_messages_per_s,
                                 settings.kit_rows_per_s / settings.ingest_rows_per_s))
        self._budget_task = asyncio.create_task(follow_loop(self.ingest_budget, share_min),
                                                name="armtrack-ingest-budget")

    async def stop(self) -> None:
        for task in (self._access_task, self._kit_check_task, self._budget_task):
            if task is not None:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
        await self.viewer.stop()
        for connection in list(self.connections.values()):
            await connection.close(1001, "server shutting down")
        for stream_id in list(self.parked_live):
            self._drop_parked(stream_id)
        await self.writer.stop()
        await self.live.stop()
        await self.live_estimation.stop()
        await self.hub.stop()
        if self.background:
            await asyncio.gather(*self.background, return_exceptions=True)
        await asyncio.get_running_loop().run_in_executor(None, self.processing.stop)
        self.db_pool.shutdown(wait=True)
        self.cpu_pool.shutdown(wait=True)
        self.export_pool.shutdown(wait=True)
        self.password_pool.shutdown(wait=True)
        self.engine.dispose()

    def count_kit_samples(self, device_id: int, session_id: int, created_at: datetime,
                          rows: int) -> None:
        """``rows`` stored by kit ``device_id`` outside its streams (an upload: session
        ``session_id``, created at ``created_at``, holding them all), in the day its open
        streams count (``kit_samples``; without one, the next counts them from the
        database). Event loop only."""
        if device_id in self.kit_samples:  # (read from the database with it, or before)
            self.kit_samples[device_id].hold(session_id, created_at, rows)

    def kit_budget(self, device_id: int) -> KitBudget:
        """The reading budget of kit ``device_id``, one for all its streams."""
        budget = self.kit_budgets.get(device_id)
        if budget is None:
            budget = self.kit_budgets[device_id] = KitBudget(
                self.settings.kit_messages_per_s, self.settings.kit_rows_per_s)
        return budget

    def park_live(self, stream_id: str, worker: LiveWorker, feedback: Any,
                  device_id: int | None = None, therapist_id: int | None = None) -> None:
        """Keep the live side (estimator, feedback's counts) of a stream whose connection
        was lost without ``bye``, for ``LIVE_PARK_S``: a resume of the stream on this
        server takes it over (``take_live``), so its live estimates need no calibration
        again and its repetitions go on. At most ``ARMTRACK_MAX_STREAMS_PER_KIT`` of one
        kit (its oldest goes: a kit dropping streams pushes out its own, not other
        patients') and ``MAX_PARKED_LIVE`` in all, shared fairly among therapists: when
        full, the oldest of the therapist holding the most goes (this one's own when it
        holds as many as any), so one therapist's kits, however many, push out their
        own sides before anyone else's."""
        worker.on_pose = None
        old = self.parked_live.pop(stream_id, None)
        if old is not None:
            old.expire.cancel()
            self._close_live(old.worker)
        if device_id is not None:
            own = [k for k, p in self.parked_live.items() if p.device_id == device_id]
            for oldest in own[:max(0, len(own) - self.settings.max_streams_per_kit + 1)]:
                self._drop_parked(oldest)
        while len(self.parked_live) >= MAX_PARKED_LIVE:
            self._drop_parked(self._evictee(therapist_id))
        loop = asyncio.get_running_loop()
        self.parked_live[stream_id] = ParkedLive(
            worker, feedback, loop.call_later(LIVE_PARK_S, self._drop_parked, stream_id),
            device_id, therapist_id)

    def _evictee(self, newcomer: int | None) -> str:
        """The parked side to let go for the ``newcomer`` therapist's: the oldest of the
        biggest holder, counting the newcomer's own as one more (at a tie: the newcomer's
        own, else the holder whose oldest is oldest)."""
        held: dict[int | None, list[str]] = {}
        for key, parked in self.parked_live.items():  # oldest first
            held.setdefault(parked.therapist_id, []).append(key)
        most = max(len(v) + (k == newcomer) for k, v in held.items())
        if newcomer in held and len(held[newcomer]) + 1 == most:
            return held[newcomer][0]
        return next(v[0] for v in held.values() if len(v) == most)

    def take_live(self, stream_id: str) -> ParkedLive | None:
        """The parked live side of ``stream_id`` (None when there is none)."""
        parked = self.parked_live.pop(stream_id, None)
        if parked is not None:
            parked.expire.cancel()
        return parked

    def _drop_parked(self, stream_id: str) -> None:
        parked = self.parked_live.pop(stream_id, None)
        if parked is not None:
            parked.expire.cancel()
            self._close_live(parked.worker)

    def _close_live(self, worker: LiveWorker) -> None:
        worker.error = worker.error or "closed"  # at once: it publishes nothing from now
        task = asyncio.get_running_loop().create_task(worker.close())
        self.background.add(task)
        task.add_done_callback(self.background.discard)

    async def run_db(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(db, *args)`` with a database session, on the database thread pool."""
        def call() -> T:
            with self.db() as db:
                return fn(db, *args)
        # in the caller's context: what ``fn`` notes for the audit log reaches the request
        context = contextvars.copy_context()
        return await asyncio.get_running_loop().run_in_executor(self.db_pool, context.run,
                                                                call)

    async def run_export(self, fn: Callable[..., T], *args: Any, owner: int = 0,
                         gone: Awaitable[Any] | None = None) -> T:
        """``fn(db, *args)``, a session's export, with a database session on one of
        ``EXPORTS_AT_ONCE`` threads of its own (``export_pool``), at most that many at once
        in this process; the others wait their turn holding no thread. Each holds the
        whole session in memory, several times over: angles.csv of a 1.89 M-row session
        took the server +595 MB, six at once +2978 MB, and the thread pool lets 40 run at
        once. Turns are shared fairly among ``owner``s (therapists' ids: ``FairTurns``).
        ``gone``: done once nobody wants the export any more; while it waits, raises
        ``ExportUnwanted`` then."""
        def call() -> T:
            # its report builds are bounded by the export turns, not counted as a request's
            UNCOUNTED.set(True)
            with self.db() as db:
                return fn(db, *args)
        context = contextvars.copy_context()  # what fn notes for the audit log
        if not await self._export_turn(owner, gone):
            raise ExportUnwanted
        try:
            return await asyncio.get_running_loop().run_in_executor(
                self.export_pool, context.run, call)
        finally:
            self.exports.release(owner)

    async def _export_turn(self, owner: int, gone: Awaitable[Any] | None) -> bool:
        """Take an export's turn (``exports``); False, holding none, once ``gone`` is done
        first (the one who asked is gone: twelve requests dropped at once were each
        built in turn all the same, another therapist's export waiting 10.5 s instead of
        0.03 s behind them)."""
        if gone is None:
            await self.exports.acquire(owner)
            return True
        turn = asyncio.ensure_future(self.exports.acquire(owner))
        watch = asyncio.ensure_future(gone)
        try:
            await asyncio.wait((turn, watch), return_when=asyncio.FIRST_COMPLETED)
        except BaseException:  # the request cancelled: a turn given meanwhile goes back
            watch.cancel()
            self._give_back(turn, owner)
            raise
        watch.cancel()
        if watch.done() and not watch.cancelled():  # the client went away
            self._give_back(turn, owner)
            return False
        return True

    def _give_back(self, turn: asyncio.Future, owner: int) -> None:
        """No export after all: the turn ``turn`` (``exports.acquire``) goes back, given or
        still waited for (then ``acquire`` gives back one given at the last moment)."""
        if not turn.done():
            turn.cancel()
        elif not turn.cancelled() and turn.exception() is None:
            self.exports.release(owner)

    async def run_password(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` (a password check or hash) on the password pool; raises
        ``PasswordsBusy`` at once when ``PASSWORD_WAITING_MAX`` are waiting or under way
        (each new name and address passes the sign-in limiter: without a bound, a burst of
        them queued minutes of hashing ahead of every sign-in). Event loop only."""
        if self._passwords_waiting >= PASSWORD_WAITING_MAX:
            raise PasswordsBusy
        self._passwords_waiting += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self.password_pool, fn,
                                                                    *args)
        finally:
            self._passwords_waiting -= 1

    async def run_cpu(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on the CPU thread pool: CPU work never blocks the event loop."""
        context = contextvars.copy_context()
        return await asyncio.get_running_loop().run_in_executor(self.cpu_pool, context.run,
                                                                fn, *args)

    def process_later(self, session_id: int, filter_name: str) -> asyncio.Future:
        """Estimate a closed session (``store.background``) without waiting; tracked until
        done. Awaiting it raises ``ProcessingFailed`` if it did not complete."""
        future = asyncio.wrap_future(self.processing.submit(session_id, filter_name))
        self.background.add(future)
        future.add_done_callback(self.background.discard)
        # a failure is logged where it happened; nobody need wait for it to be seen
        future.add_done_callback(lambda done: done.cancelled() or done.exception())
        return future

    async def end_session_streams(self, session_id: int, reason: str) -> None:
        """Close the open streams of a session (1000, ``reason``), wait until what they
        sent is stored, and let go of the session's live sides, open or parked (a lost
        stream's, kept for a resume that can no longer come): none publishes a pose of
        the session after this returns."""
        for stream_id, connection in list(self.connections.items()):
            state = self.streams.get(stream_id)
            if state is not None and state.session_id == session_id:
                await connection.close(1000, reason)
                await state.idle.wait()
                await connection.ended.wait()  # its clean-up is over: it marks nothing after
        for stream_id, parked in list(self.parked_live.items()):
            if parked.worker.session_id == session_id:
                self._drop_parked(stream_id)

    async def _check_kits(self, every_s: float) -> None:
        """Every ``every_s`` seconds, close the open streams (and parked live sides) of
        kits revoked or erased since they opened: a revoke or an erase closes those of its
        own instance at once, but another instance behind the same database (or a stream
        whose hello was read just before the revoke) learns it only from the database.
        Before, a kit revoked on one instance streamed on into the other, acked."""
        await every(every_s, self.recheck_kits, log=log, failed="kit check failed")

    async def recheck_kits(self) -> int:
        """Close the streams of every open kit whose token no longer holds (revoked, or
        the kit erased with its patient); their number of kits."""
        open_kits = {c.device_id for c in self.connections.values()} \
            | {p.device_id for p in self.parked_live.values() if p.device_id is not None}
        if not open_kits:
            return 0

        def valid(db) -> set[int]:
            return set(db.scalars(select(models.Device.id).where(
                models.Device.id.in_(open_kits), models.Device.revoked_at.is_(None))))
        gone = open_kits - await self.run_db(valid)
        for device_id in gone:
            log.info("kit %s was revoked or erased: closing its streams", device_id)
            await self.revoke_device(device_id)
        return len(gone)

    async def revoke_device(self, device_id: int) -> None:
        """Close every open stream of a device with 4401, and let go of its parked live
        sides (a revoked kit resumes nothing)."""
        for connection in list(self.connections.values()):
            if connection.device_id == device_id:
                await connection.close(4401, "device token revoked")
                await connection.ended.wait()  # its live side is parked, or closed, by now
        for stream_id, parked in list(self.parked_live.items()):
            if parked.device_id == device_id:
                self._drop_parked(stream_id)
