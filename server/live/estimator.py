"""One streaming session's live estimation: its streaming ``Pipeline``, the running
range of motion after calibration, and the pose to publish. Pure computation: it runs
wherever ``estimation`` puts it (the live estimation process, or a thread)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from datetime import datetime
from zoneinfo import ZoneInfo

import numpy as np
from armtrack.estimator.arm.forward import POINTS
from armtrack.estimator.arm.joints import REPORTED_ANGLES, SEGMENTS
from armtrack.estimator.calibration.quality import PLACES
from armtrack.estimator.jit import compiler
from armtrack.estimator.metrics.elbow_pivot import turn_terms, up_of_sensor_y
from armtrack.estimator.metrics.rom import CALIBRATION_TAIL_S
from armtrack.estimator.pipeline import EstimateArrays, Pipeline, PipelineConfig
from armtrack.estimator.recording import Mark
from armtrack.estimator.recording.points import PointsFrame
from armtrack.estimator.scalar_rotations import quat_from_rows

from ..ingest.points import POINT_PREFIX
from ..ingest.protocol import MarkMessage, Samples
from .encoded import EncodedPose

#: Stream seconds after which a sensor named in hello that sent nothing is left out of
#: the live estimates (the others would wait for it for ever).
SILENT_SENSOR_S = 10.0
#: Stream seconds a sensor that sent before may fall behind the newest sample of the
#: kit's others before the live view leaves it out (``_drop_stopped``); it is left out
#: when it has also sent nothing for ``STOPPED_SENSOR_S`` seconds of the server's clock,
#: or when the others' samples the live estimates hold waiting for it pass
#: ``STOPPED_HELD_ROWS`` (a kit that sends one sensor and not the others, fast). 30 s: a
#: kit's message of 1000 rows (the most, ``ingest.protocol.MAX_ROWS``) is 10 s at 100 Hz,
#: 20 s at 50 Hz, so its sensors may lag one another by that much as it sends (at 10 s
#: the upper arm of a kit sending 1000-row messages was taken for stopped).
STOPPED_SENSOR_S = 30.0
#: The most rows of the other sensors the live estimates hold for a sensor that fell
#: behind (about 0.1 kB a row: a few MB; 100 s of a 3-sensor kit at 100 Hz).
STOPPED_HELD_ROWS = 30_000
#: Rate of the angle trail a pose carries [Hz, on the stream's clock]: every estimate
#: since the previous pose, thinned to this rate. The live repetition count
#: (``server/live/motion.py``) reads the trail, not the poses, which come one per batch
#: and so thin out when the server is busy (half a second apart and more: the counter
#: then saw every sample as its own stretch and counted nothing). 25 Hz is 8 times the
#: counter's 3 Hz low-pass.
TRAIL_HZ = 25.0
#: Decimals of the trail's angles [deg]: 0.01° is far below any estimate's accuracy.
TRAIL_DECIMALS = 2
#: The most estimates a trail keeps until taken (the oldest go): two minutes at
#: ``TRAIL_HZ``, for a backlog sent at once after a lost link (the kit's feedback counts
#: its repetitions on the trail too, so a backlog counts like a live stream).
TRAIL_MAX = 3000
#: Decimals of the trail's forearm turn terms (pull [m/s²], ω⊥² [rad²/s²]).
TURN_DECIMALS = 3
#: A forearm-only kit's readings kept to meet their estimates [s] (``_forearm_turns``).
RAW_KEEP_S = 5.0
#: The forearm's index in ``SEGMENTS`` (``R_world_segment``'s second axis).
FOREARM = SEGMENTS.index("forearm")


class RunningRange:
    """Per angle (``REPORTED_ANGLES``), the least and greatest value so far [deg], from
    ``start_s`` on."""

    def __init__(self) -> None:
        self.low = np.full(len(REPORTED_ANGLES), np.inf)
        self.high = np.full(len(REPORTED_ANGLES), -np.inf)
        self.start_s = -np.inf
        self._as_dict: dict[str, dict[str, float]] | None = {}

    def update(self, t: np.ndarray, radians: np.ndarray) -> None:
        """Angles ``radians`` (n, len(REPORTED_ANGLES)), as the pipeline's kernel gives
        them, at times ``t`` (n,). A chunk with a NaN in an angle changes nothing of that
        angle."""
        if _extend_range(t, radians, self.start_s, self.low, self.high):
            self._as_dict = None  # rebuilt when asked

    def as_dict(self) -> dict[str, dict[str, float]]:
        if self._as_dict is None:
            self._as_dict = {k: {"min": lo, "max": hi, "range": hi - lo}
                             for k, lo, hi in zip(REPORTED_ANGLES, self.low.tolist(),
                                                  self.high.tolist(), strict=True) if lo <= hi}
        return self._as_dict


def _extend_range_loop(t, radians, start_s, low, high) -> bool:
    """``low``/``high`` [deg] widened, in place, by each angle's least and greatest value
    at times ≥ ``start_s`` (none when the angle has a NaN there); True if any changed.
    One pass (compiled by numba: a dozen array calls a chunk before)."""
    changed = False
    for a in range(radians.shape[1]):
        lo, hi, kept, nan = np.inf, -np.inf, False, False
        for i in range(radians.shape[0]):
            if t[i] >= start_s:
                v = radians[i, a]
                if v != v:
                    nan = True
                    break
                kept = True
                lo = min(lo, v)
                hi = max(hi, v)
        if kept and not nan:
            lo_deg, hi_deg = lo * _DEG_PER_RAD, hi * _DEG_PER_RAD  # as np.rad2deg
            if lo_deg < low[a]:
                low[a] = lo_deg
                changed = True
            if hi_deg > high[a]:
                high[a] = hi_deg
                changed = True
    return changed


_DEG_PER_RAD = 180.0 / np.pi


def _compile_extend_range():
    jit = compiler(nogil=True)
    return jit(_extend_range_loop) if jit else _extend_range_loop


_extend_range = _compile_extend_range()


class AngleTrail:
    """The estimates since the last ``take``, thinned to at most one per 1/``rate_hz``
    of the stream's clock (the first estimate of each such slot is kept)."""

    def __init__(self, rate_hz: float):
        self._rate = rate_hz
        self._last_slot = -np.inf
        self._t: list[np.ndarray] = []
        self._angles: list[np.ndarray] = []
        self._turns: list[np.ndarray] = []  # a forearm-only kit's (n, 2) turn terms
        self._count = 0

    def add(self, t: np.ndarray, radians: np.ndarray, turn: np.ndarray | None = None
            ) -> None:
        """Estimates at times ``t`` [s] (n,), angles ``radians`` (n, len(REPORTED_ANGLES));
        ``turn``: a forearm-only kit's (n, 2) pull and ``ω⊥²`` at those times
        (``elbow_pivot.turn_terms``), else None."""
        slots = np.floor(np.asarray(t) * self._rate + 1e-6)  # a stamp on a boundary opens it
        keep = np.empty(len(slots), dtype=bool)
        keep[:1] = slots[:1] > self._last_slot
        keep[1:] = (slots[1:] > slots[:-1]) & (slots[1:] > self._last_slot)
        if keep.any():
            self._t.append(np.asarray(t)[keep])
            self._angles.append(radians[keep])
            if turn is not None:
                self._turns.append(turn[keep])
            self._last_slot = float(slots[keep][-1])
            self._count += int(keep.sum())
            while self._count > TRAIL_MAX and len(self._t) > 1:
                self._count -= self._t.pop(0).size
                self._angles.pop(0)
                if self._turns:
                    self._turns.pop(0)

    def take(self) -> tuple[list[float], list[list[float | None]], list[list[float]] | None]:
        """The kept times [s], angles [deg] (rows in ``REPORTED_ANGLES`` order; a NaN
        stays NaN, which the pose's JSON writes as null) and the forearm's turn terms (or
        None: not a forearm-only kit), then forgets them."""
        if not self._t:
            return [], [], None
        t = np.concatenate(self._t)[-TRAIL_MAX:]
        angles = np.vstack(self._angles)[-TRAIL_MAX:]
        turns = (np.round(np.vstack(self._turns)[-TRAIL_MAX:], TURN_DECIMALS).tolist()
                 if self._turns else None)
        self._t, self._angles, self._turns, self._count = [], [], [], 0
        return t.tolist(), np.round(np.rad2deg(angles), TRAIL_DECIMALS).tolist(), turns


#: ``LiveEstimator.process``'s answer when the newest estimates wait for the pose rate.
HELD = "held"


class LiveEstimator:
    """One streaming session's estimation, where the estimates are computed: its
    ``Pipeline``, running range of motion, and the sensors left out for silence."""

    def __init__(self, config: PipelineConfig, session_id: int, max_rate_hz: float,
                 points_frame: PointsFrame | None = None,
                 gyr_bias_priors: Mapping[str, tuple[float, float, float]] | None = None,
                 clinic_timezone: str = "UTC"):
        self.pipeline = Pipeline(config, points_frame=points_frame,
                                 gyr_bias_priors=gyr_bias_priors)
        #: the clinic's clock (``ARMTRACK_CLINIC_TIMEZONE``), which a warning's time is in
        self._zone = ZoneInfo(clinic_timezone)
        self.session_id = session_id
        self._min_interval = 1.0 / max_rate_hz
        self._pose_end = -np.inf
        self.rom = RunningRange()
        self.warnings: list[str] = []
        self._dropped: set[str] = set()
        #: sensors left out after they stopped sending: name → {"t": its last sample [s,
        #: stream clock], "at": when it came [Unix s]}
        self.stopped: dict[str, dict[str, float]] = {}
        self._heard: dict[str, tuple[float, float]] = {}  # sensor → (monotonic, Unix) s
        self._resumed: set[str] = set()
        self.estimates = 0
        self._first_t = np.inf
        self._last_pose = -np.inf  # monotonic time the last pose was returned
        self._unshown: EstimateArrays | None = None  # the newest estimates not yet a pose
        self._trail = AngleTrail(TRAIL_HZ)
        #: a forearm-only kit (elbow flexion may be the straight arm raised): its forearm
        #: readings (t, a_y, g_x, g_z) kept to meet the estimates (``_forearm_turns``)
        self._forearm_only = "forearm" in config.sensors and "upper_arm" not in config.sensors
        self._forearm_rows: list[np.ndarray] = []

    def _drop_silent(self, t: float) -> None:
        if t - self._first_t < SILENT_SENSOR_S or self.pipeline.calibration is not None:
            return
        for sensor in self.pipeline.silent_sensors():
            self.pipeline.drop_sensor(sensor)
            self._dropped.add(sensor)
            self.warnings.append(f"sensor {sensor} sent nothing in {SILENT_SENSOR_S:g} s: "
                                 "the live view goes on without it")

    def _drop_stopped(self) -> EstimateArrays | None:
        """Leave out of the live view a sensor that stopped sending while the others go on
        (``STOPPED_SENSOR_S``, ``STOPPED_HELD_ROWS``): the estimates then go on without it,
        and the others' samples are no longer held for it. Its later samples are stored
        all the same (the offline estimation at close takes every sample). Returns the
        estimates that waited for it (None: none)."""
        pipeline = self.pipeline
        waited: list[EstimateArrays] = []
        while True:  # the furthest behind first; then the rule again without it
            last = {s: t for s, t in pipeline.last_times().items() if t > -np.inf}
            if len(last) < 2:
                break
            sensor, t = min(last.items(), key=lambda item: item[1])
            if max(last.values()) - t < STOPPED_SENSOR_S:
                break
            now = time.monotonic()
            heard_at, heard_unix = self._heard.get(sensor, (now, time.time()))
            if now - heard_at < STOPPED_SENSOR_S and pipeline.held_rows() < STOPPED_HELD_ROWS:
                break
            estimates = pipeline.stop_sensor(sensor)
            if estimates is not None:
                waited.append(estimates)
            self._dropped.add(sensor)
            self.stopped[sensor] = {"t": t, "at": heard_unix}
            # the clinic's time, as the pages show times; not the server machine's clock
            when = datetime.fromtimestamp(heard_unix, self._zone).strftime("%H:%M")
            self.warnings.append(
                f"the {PLACES.get(sensor, sensor)} sensor stopped sending at {when} "
                f"(stream time {t:.0f} s) — check its battery and its connection; angles "
                "that need it are not shown live (everything it sent is stored)")
        if not waited:
            return None
        return waited[0] if len(waited) == 1 else EstimateArrays.concatenate(waited)

    def _forearm_turns(self, estimates: EstimateArrays) -> np.ndarray | None:
        """A forearm-only kit's turn terms at the estimates' times (n, 2): the forearm's
        pull along its axis that is not gravity and ``ω⊥²`` (``elbow_pivot.turn_terms``),
        from its readings (the estimates' times are its own) and the estimated forearm's
        upward axis; None for any other kit or without readings."""
        if not self._forearm_only or not self._forearm_rows:
            return None
        rows = np.vstack(self._forearm_rows)
        t = estimates.t
        ay = np.interp(t, rows[:, 0], rows[:, 1])
        gyr = np.column_stack([np.interp(t, rows[:, 0], rows[:, 2]), np.zeros(len(t)),
                               np.interp(t, rows[:, 0], rows[:, 3])])
        calibration = self.pipeline.calibration  # the sensor's +Y in the forearm's frame
        sensor_y = (calibration.R_sensor_segment["forearm"][1] if calibration is not None
                    and "forearm" in calibration.R_sensor_segment else None)
        pull, across = turn_terms(ay, gyr, up_of_sensor_y(
            estimates.R_world_segment[:, FOREARM, 2, :], sensor_y))
        self._forearm_rows = [rows[rows[:, 0] >= t[-1] - RAW_KEEP_S]]
        return np.column_stack([pull, across])

    def process(self, items: list[Samples | MarkMessage]) -> EncodedPose | str | None:
        """Feed, poll, and the newest pose, encoded; None when nothing is new, ``HELD``
        when one was returned less than 1/``max_rate_hz`` ago (the newest estimates are
        kept: a call after that interval, with no new messages, returns them as a pose, so
        a stream that pauses still shows its last estimates)."""
        pipeline = self.pipeline
        for item in items:
            if isinstance(item, Samples):
                rows = item.rows
                if item.sensor in self._dropped:
                    if item.sensor in self.stopped and item.sensor not in self._resumed:
                        self._resumed.add(item.sensor)
                        self.warnings.append(
                            f"the {PLACES.get(item.sensor, item.sensor)} sensor sends "
                            "again: it is stored, and shown live from the next session")
                    continue  # it came too late for the live view; it is stored all the same
                if item.sensor.startswith(POINT_PREFIX):  # docs/extensions/points.md
                    pipeline.feed_points(item.sensor[len(POINT_PREFIX):], rows[:, 0],
                                         rows[:, 1:4])
                    continue
                first = float(rows[0, 0])
                if first < self._first_t:
                    self._first_t = first
                pipeline.feed_rows(item.sensor, rows)
                self._heard[item.sensor] = (time.monotonic(), time.time())
                if self._forearm_only and item.sensor == "forearm":
                    self._forearm_rows.append(np.asarray(rows, dtype=float)[:, [0, 2, 4, 6]])
                if pipeline.calibration is None:
                    self._drop_silent(float(rows[-1, 0]))
            else:
                self.pipeline.add_mark(Mark(item.t, item.label))
                if item.label in ("end:npose", "end:tpose"):
                    self._pose_end = max(self._pose_end, item.t)
                    self.rom.start_s = self._pose_end + CALIBRATION_TAIL_S
        waited = self._drop_stopped()
        # the kernels' arrays, not named views: a pose needs only their last rows
        estimates = pipeline.poll_arrays()
        if waited is not None:
            estimates = waited if estimates is None else \
                EstimateArrays.concatenate([waited, estimates])
        if estimates is not None:
            self.estimates += len(estimates.t)
            self.rom.update(estimates.t, estimates.angles)
            self._trail.add(estimates.t, estimates.angles, self._forearm_turns(estimates))
            self._unshown = estimates
        estimates = self._unshown
        if estimates is None:
            return None
        now = time.monotonic()
        if now - self._last_pose < self._min_interval:
            return HELD  # published recently enough: the range of motion is kept all the same
        self._last_pose = now
        self._unshown = None
        trail_t, trail_deg, trail_turns = self._trail.take()
        segments = estimates.R_world_segment[-1].reshape(len(SEGMENTS), 9).tolist()
        return EncodedPose.encode({
            "kind": "pose", "session_id": self.session_id, "t": float(estimates.t[-1]),
            "angles_deg": dict(zip(REPORTED_ANGLES, np.rad2deg(estimates.angles[-1]).tolist(),
                                   strict=True)),
            "positions_m": dict(zip(POINTS, estimates.positions[-1].tolist(), strict=True)),
            "segments_q": {s: quat_from_rows(*rows)
                           for s, rows in zip(SEGMENTS, segments, strict=True)},
            "rom_deg": self.rom.as_dict(),
            "estimates": self.estimates,
            "warnings": list(self.warnings),
            **({"stopped_sensors": self.stopped} if self.stopped else {}),
            "trail": {"t": trail_t, "angles_deg": trail_deg,
                      **({"forearm_turn": trail_turns} if trail_turns is not None else {})},
            **({"elbow_source": pipeline.elbow_source} if pipeline.gamma is not None else {}),
        })
