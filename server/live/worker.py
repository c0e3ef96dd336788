"""Live estimation. A ``LiveWorker`` per streaming session holds its streaming
``Pipeline`` and running range of motion; the ``LiveBatcher`` runs every worker's accepted
messages off the event loop in batches: every ``interval_s`` one call on the compute pool
(per pool thread, workers shared out by session) feeds and polls every worker that has
something new, and the newest poses are published. So the thread hops per second do not
grow with the number of patients, and a message waits at most ``interval_s`` plus the
batch's work before its pose is out.

A worker that fails stops estimating and says why; the stream, its stored data and the
other workers go on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from concurrent.futures import Executor
from typing import Any

import numpy as np
from armtrack.estimator.arm.joints import REPORTED_ANGLES, SEGMENTS
from armtrack.estimator.pipeline import Pipeline, PipelineConfig
from armtrack.estimator.recording import Mark
from armtrack.estimator.scalar_rotations import quat_from_rows

from ..ingest.protocol import MarkMessage, Samples
from .hub import LiveHub

log = logging.getLogger("armtrack.live")

#: Seconds after the last calibration pose's end still counted as calibration.
CALIBRATION_TAIL_S = 2.5
#: Stream seconds after which a sensor named in hello that sent nothing is left out of
#: the live estimates (the others would wait for it for ever).
SILENT_SENSOR_S = 10.0


class RunningRange:
    """Per angle (``REPORTED_ANGLES``), the least and greatest value so far [deg], from
    ``start_s`` on."""

    def __init__(self) -> None:
        self.low = np.full(len(REPORTED_ANGLES), np.inf)
        self.high = np.full(len(REPORTED_ANGLES), -np.inf)
        self.start_s = -np.inf
        self._as_dict: dict[str, dict[str, float]] | None = {}

    def update(self, t: np.ndarray, degrees: np.ndarray) -> None:
        """``degrees`` (len(REPORTED_ANGLES), n) at times ``t`` (n,)."""
        keep = t >= self.start_s
        if not keep.all():
            if not keep.any():
                return
            t, degrees = t[keep], degrees[:, keep]
        low = np.fmin(self.low, degrees.min(axis=1))  # a NaN chunk changes nothing
        high = np.fmax(self.high, degrees.max(axis=1))
        if (low != self.low).any() or (high != self.high).any():
            self.low, self.high = low, high
            self._as_dict = None  # rebuilt when asked

    def as_dict(self) -> dict[str, dict[str, float]]:
        if self._as_dict is None:
            self._as_dict = {k: {"min": lo, "max": hi, "range": hi - lo}
                             for k, lo, hi in zip(REPORTED_ANGLES, self.low.tolist(),
                                                  self.high.tolist(), strict=True) if lo <= hi}
        return self._as_dict


class LiveBatcher:
    """Runs the pending messages of all live workers in batches (see the module)."""

    def __init__(self, hub: LiveHub, executor: Executor, threads: int, interval_s: float):
        self._hub = hub
        self._executor = executor
        self._threads = max(1, threads)
        self._interval = interval_s
        self._ready: set[LiveWorker] = set()
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        self.batches = 0

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="armtrack-live-batcher")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    def ready(self, worker: LiveWorker) -> None:
        self._ready.add(worker)
        self._wake.set()

    def forget(self, worker: LiveWorker) -> None:
        self._ready.discard(worker)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            await asyncio.sleep(self._interval)  # let a batch gather
            self._wake.clear()
            workers, self._ready = self._ready, set()
            # take each worker's messages here, on the loop, so feed() never races a batch
            jobs = [(w, w.take()) for w in workers]
            shares = [jobs[i::self._threads] for i in range(self._threads)]
            results = await asyncio.gather(*(
                loop.run_in_executor(self._executor, _process_share, share)
                for share in shares if share))
            self.batches += 1
            now = time.monotonic()
            for share in results:
                for worker, outcome, received in share:
                    worker.publish(outcome, received, now)


def _process_share(jobs: list[tuple[LiveWorker, tuple[list, float]]]
                   ) -> list[tuple[LiveWorker, dict[str, Any] | Exception | None, float]]:
    """On a compute thread: each worker's messages through its pipeline. One worker's
    failure is its own: it is returned, not raised."""
    out = []
    for worker, (items, received) in jobs:
        try:
            outcome: dict[str, Any] | Exception | None = worker.process(items)
        except Exception as exc:
            outcome = exc
        out.append((worker, outcome, received))
    return out


class LiveWorker:
    def __init__(self, config: PipelineConfig, *, patient_id: int, session_id: int,
                 hub: LiveHub, batcher: LiveBatcher, max_rate_hz: float):
        self.pipeline = Pipeline(config)
        self.patient_id = patient_id
        self.session_id = session_id
        self._hub = hub
        self._batcher = batcher
        self._min_interval = 1.0 / max_rate_hz
        self._pending: list[Samples | MarkMessage] = []
        self._received = 0.0  # monotonic time the newest pending message arrived
        self._pose_end = -np.inf
        self.rom = RunningRange()
        self.error: str | None = None
        self.warnings: list[str] = []
        self._dropped: set[str] = set()
        self.estimates = 0
        self._first_t = np.inf
        self._last_publish = 0.0

    def feed(self, item: Samples | MarkMessage, received: float) -> None:
        """An accepted message; ``received`` [s, ``time.monotonic``] when it arrived."""
        if self.error is None:
            self._pending.append(item)
            self._received = received
            self._batcher.ready(self)

    def take(self) -> tuple[list[Samples | MarkMessage], float]:
        """The pending messages and when the newest arrived (on the event loop)."""
        items, self._pending = self._pending, []
        return items, self._received

    async def close(self) -> None:
        self.error = self.error or "closed"
        self._batcher.forget(self)

    def publish(self, outcome: dict[str, Any] | Exception | None, received: float,
                now: float) -> None:
        """On the event loop, after a batch: the pose (or the failure) goes out."""
        if isinstance(outcome, Exception):
            log.error("live estimation of session %s failed", self.session_id,
                      exc_info=outcome)
            self.error = f"live estimation stopped: {outcome}"
            self._hub.publish(self.patient_id, {"kind": "error", "session_id": self.session_id,
                                                "reason": self.error})
        elif outcome is not None:
            self._last_publish = now
            outcome["latency_s"] = now - received  # newest sample received → published
            self._hub.publish(self.patient_id, outcome)

    def _drop_silent(self, t: float) -> None:
        if t - self._first_t < SILENT_SENSOR_S or self.pipeline.calibration is not None:
            return
        for sensor in self.pipeline.silent_sensors():
            self.pipeline.drop_sensor(sensor)
            self._dropped.add(sensor)
            message = (f"sensor {sensor} sent nothing in {SILENT_SENSOR_S:g} s: the live "
                       "view goes on without it")
            self.warnings.append(message)
            log.warning("session %s: %s", self.session_id, message)

    def process(self, items: list[Samples | MarkMessage]) -> dict[str, Any] | None:
        """On a compute thread: feed, poll, and the newest pose (None when nothing new or
        one was published less than 1/``max_rate_hz`` ago)."""
        if self.error is not None:
            return None
        for item in items:
            if isinstance(item, Samples):
                rows = item.rows
                if item.sensor in self._dropped:
                    continue  # it came too late for the live view; it is stored all the same
                self._first_t = min(self._first_t, float(rows[0, 0]))
                mag = rows[:, 7:10] if not np.isnan(rows[0, 7]) else None
                self.pipeline.feed(item.sensor, rows[:, 0], rows[:, 1:4], rows[:, 4:7], mag)
                self._drop_silent(float(rows[-1, 0]))
            else:
                self.pipeline.add_mark(Mark(item.t, item.label))
                if item.label in ("end:npose", "end:tpose"):
                    self._pose_end = max(self._pose_end, item.t)
                    self.rom.start_s = self._pose_end + CALIBRATION_TAIL_S
        estimates = self.pipeline.poll()
        n = len(estimates)
        if n == 0:
            return None
        self.estimates += n
        degrees = np.rad2deg(np.stack([estimates.angles[k] for k in REPORTED_ANGLES]))
        self.rom.update(estimates.t, degrees)
        if time.monotonic() - self._last_publish < self._min_interval:
            return None  # published recently enough: the range of motion is kept all the same
        return {
            "kind": "pose", "session_id": self.session_id, "t": float(estimates.t[-1]),
            "angles_deg": dict(zip(REPORTED_ANGLES, degrees[:, -1].tolist(), strict=True)),
            "positions_m": {k: v[-1].tolist() for k, v in estimates.positions.items()},
            "segments_q": {s: quat_from_rows(*estimates.R_world_segment[s][-1].ravel().tolist())
                           for s in SEGMENTS},
            "rom_deg": self.rom.as_dict(),
            "estimates": self.estimates,
            "warnings": self.warnings,
        }
