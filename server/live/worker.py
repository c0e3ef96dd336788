"""Live estimation. Each streaming session has a ``LiveWorker`` here, on the event loop
(its accepted messages, and its poses going out), and a ``LiveEstimator`` (its streaming
``Pipeline`` and running range of motion) where the estimates are computed: in the live
estimation process by default, or on this process's thread pool (``estimation``). The
``LiveBatcher`` runs every worker's new messages in batches: at most every ``interval_s``
one round trip feeds and polls every estimator that has something new, and the newest
poses are published. So the hops per second do not grow with the number of patients, and
a message waits at most ``interval_s`` plus two batches' work before its pose is out.

An estimator that fails stops and says why; the stream, its stored data and the other
estimators go on.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections.abc import Callable, Mapping
from typing import Any

from armtrack.estimator.pipeline import PipelineConfig
from armtrack.estimator.recording.points import PointsFrame

from ..ingest.protocol import MarkMessage, Samples
from .estimation import Estimation, LiveFailure, Opening, Outcome, to_wire
from .hub import LiveHub

log = logging.getLogger("armtrack.live")


class LiveBatcher:
    """Runs the pending messages of all live workers in batches (see the module)."""

    def __init__(self, estimation: Estimation, interval_s: float):
        self._estimation = estimation
        self._interval = interval_s
        self._ready: set[LiveWorker] = set()
        self._closed: list[int] = []  # keys of estimators to let go with the next batch
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        self._keys = itertools.count(1)
        self._under_way: set[asyncio.Task] = set()  # batches sent, not yet published
        self.batches = 0

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="armtrack-live-batcher")

    async def stop(self) -> None:
        tasks = [t for t in (self._task, *self._under_way) if t is not None]
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task

    def new_key(self) -> int:
        """A worker's key: names its estimator where the estimates are computed."""
        return next(self._keys)

    def ready(self, worker: LiveWorker) -> None:
        self._ready.add(worker)
        self._wake.set()

    def forget(self, worker: LiveWorker) -> None:
        self._ready.discard(worker)
        self._closed.append(worker.key)
        self._wake.set()

    async def _run(self) -> None:
        started = -float("inf")  # monotonic start of the last batch
        # up to ``depth`` batches under way: the next is sent while one is computed
        slots = asyncio.Semaphore(self._estimation.depth)
        while True:
            await self._wake.wait()
            # let a batch gather for what is left of the interval since the last one
            # started: when batches take longer than that, the next goes at once
            await asyncio.sleep(max(0.0, started + self._interval - time.monotonic()))
            await slots.acquire()
            started = time.monotonic()
            self._wake.clear()
            workers, self._ready = self._ready, set()
            closed, self._closed = self._closed, []
            # take each worker's messages here, on the loop, so feed() never races a batch
            jobs, received = [], {}
            for worker in workers:
                opening, items, received[worker.key] = worker.take()
                jobs.append((worker.key, opening, to_wire(items)))
            self.batches += 1
            task = asyncio.create_task(self._publish(
                self.batches, jobs, closed, {w.key: w for w in workers}, received, slots))
            self._under_way.add(task)
            task.add_done_callback(self._under_way.discard)

    async def _publish(self, batch: int, jobs: list, closed: list[int],
                       workers: dict[int, LiveWorker], received: dict[int, float],
                       slots: asyncio.Semaphore) -> None:
        """One batch's round trip, then its poses out."""
        try:
            outcomes = await self._estimation.run(jobs, closed)
        except Exception as exc:  # a fault of the estimation side itself: the batch's
            # workers lost these messages (and maybe their estimator's opening): they stop
            # and say why, rather than go on with a gap
            log.exception("a live estimation batch failed")
            reason = f"{type(exc).__name__}: {exc}"
            outcomes = [(key, LiveFailure(reason, reason)) for key, _, _ in jobs]
        finally:
            slots.release()
        now = time.monotonic()
        for key, outcome in outcomes:
            worker = workers.get(key)
            if worker is not None:
                worker.publish(outcome, received[key], now, batch)


class LiveWorker:
    """One streaming session's live side, on the event loop: takes its accepted messages
    (``feed``), hands them to the batcher, publishes what its estimator returns."""

    def __init__(self, config: PipelineConfig, *, patient_id: int, session_id: int,
                 hub: LiveHub, batcher: LiveBatcher, max_rate_hz: float,
                 points_frame: PointsFrame | None = None,
                 gyr_bias_priors: Mapping[str, tuple[float, float, float]] | None = None,
                 clinic_timezone: str = "UTC"):
        self.patient_id = patient_id
        self.session_id = session_id
        self.key = batcher.new_key()
        self._hub = hub
        self._batcher = batcher
        #: what makes the estimator; sent with the first batch, then None
        self._opening: Opening | None = Opening(config, session_id, max_rate_hz, points_frame,
                                                gyr_bias_priors, clinic_timezone)
        self._pending: list[Samples | MarkMessage] = []
        self._pose_interval = 1.0 / max_rate_hz  # [s]
        self._fed_seq = -1  # the highest seq fed: a resumed stream sends some again
        self._received = 0.0  # monotonic time the newest pending message arrived
        self._warned = 0
        self._batch = 0  # number of the batch whose outcome was published last
        self.error: str | None = None
        #: called with each published pose (the kit feedback extension); None: nobody
        self.on_pose: Callable[[Mapping[str, Any]], None] | None = None

    def feed(self, item: Samples | MarkMessage, received: float) -> None:
        """An accepted message; ``received`` [s, ``time.monotonic``] when it arrived. One
        fed already (a resumed stream sends again what was not stored yet) is skipped."""
        if item.seq <= self._fed_seq:
            return
        self._fed_seq = item.seq
        if self.error is None:
            self._pending.append(item)
            self._received = received
            self._batcher.ready(self)

    def take(self) -> tuple[Opening | None, list[Samples | MarkMessage], float]:
        """(the estimator's opening, once), the pending messages, and when the newest
        arrived (on the event loop)."""
        opening, self._opening = self._opening, None
        items, self._pending = self._pending, []
        return opening, items, self._received

    def _ask_again(self) -> None:
        if self.error is None:
            self._batcher.ready(self)

    async def close(self) -> None:
        self.error = self.error or "closed"
        self._batcher.forget(self)

    def publish(self, outcome: Outcome, received: float, now: float, batch: int = 0) -> None:
        """On the event loop, after batch number ``batch``: the pose (or the failure) goes
        out, unless a later batch's already did."""
        if batch < self._batch:
            return
        self._batch = batch
        if isinstance(outcome, str):  # HELD: the newest estimates wait for the pose
            # rate: ask again then, messages or not (a paused stream shows where it got to)
            asyncio.get_running_loop().call_later(self._pose_interval, self._ask_again)
            return
        if isinstance(outcome, LiveFailure):
            log.error("live estimation of session %s failed: %s", self.session_id,
                      outcome.details)
            if self.error is None:
                self.error = f"live estimation stopped: {outcome.reason}"
                self._hub.publish(self.patient_id, {
                    "kind": "error", "session_id": self.session_id, "reason": self.error})
        elif outcome is not None and self.error is None:
            for message in outcome.warnings[self._warned:]:
                log.warning("session %s: %s", self.session_id, message)
            self._warned = len(outcome.warnings)
            # newest sample received → published
            self._hub.publish(self.patient_id, outcome.with_field("latency_s", now - received))
            if self.on_pose is not None:
                self.on_pose(outcome)
