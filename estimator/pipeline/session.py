"""The estimation pipeline of one session: calibrate → orient → segment orientations →
joint angles → positions. Batch and streaming are the same code.

Every sensor's filter runs as its samples arrive (filters are causal). Nothing is
estimated until calibration is final (``CalibrationPlan.final_time``) and every sensor's
data have passed that time; then estimates are given at the reference sensor's sample
times from its first sample on, each as soon as every other sensor has a sample at or
after it (their orientations are interpolated there by slerp). ``finish`` gives the rest,
holding a sensor's last orientation past its last sample. So a recording fed whole, or in
chunks of any size and any interleaving of sensors, gives the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..arm.compiled import CompiledJoints
from ..arm.coverage import ANGLES_OF_SENSOR
from ..arm.forward import POINTS
from ..arm.inverse import JointAngleParams
from ..arm.joints import REPORTED_ANGLES, SEGMENT_OF_SENSOR, SEGMENTS
from ..body import SENSOR_NAMES, SegmentLengths, Side
from ..calibration import CalibrationPlan, poses_from_marks
from ..errors import InvalidArgument
from ..orientation import DEFAULT_FILTER, GYRO_DELAY_FILTERS, LearntGyroBias, check_gyro_delay
from ..orientation.qcf import QcfParams
from ..recording import Mark, Pose
from ..recording.points import PointsFrame
from .calibrate import Calibration, biases_from_poses, calibrate
from .constraints import DRIFT_RATE_PRIOR, HeadingConstraint, mean_turn, turned_angle
from .drift import taken_at
from .estimates import REFERENCE_ORDER, EstimateArrays, Estimates
from .magnetic import disagreeing_sensors, disagreement_warning
from .segment_kernel import segment_orientations
from .sway import SwayBlocks, retold_lean
from .tracks import SensorTrack
from .wrist_points import MAX_POINTS_LAG_S, GammaElbow, WristTrack


@dataclass(frozen=True)
class PipelineConfig:
    """A session's fixed facts: ``side``, segment ``lengths`` [m], the ``sensors`` worn,
    the orientation ``filter`` by name, the joint-angle parameters, and ``gyro_delay_s``,
    how far the kit's gyroscopes lag its accelerometers [s] (the kit's declaration,
    ``docs/extensions/gyro-delay.md``; 0: in step)."""

    side: Side
    lengths: SegmentLengths
    sensors: tuple[str, ...]
    filter: str = DEFAULT_FILTER
    joint_params: JointAngleParams = field(default_factory=JointAngleParams)
    gyro_delay_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "gyro_delay_s", check_gyro_delay(self.gyro_delay_s))
        if self.gyro_delay_s and self.filter not in GYRO_DELAY_FILTERS:
            raise InvalidArgument(f"filter {self.filter!r} cannot take a gyroscope delay "
                                  f"(gyro_delay_s {self.gyro_delay_s} s); "
                                  f"{', '.join(sorted(GYRO_DELAY_FILTERS))} can")
        unknown = [s for s in self.sensors if s not in SENSOR_NAMES]
        if unknown or not self.sensors:
            raise InvalidArgument(f"sensors must be some of {SENSOR_NAMES}, got {self.sensors}")

    @property
    def reference(self) -> str:
        return next(s for s in REFERENCE_ORDER if s in self.sensors)


class Pipeline:
    """Feed samples with ``feed``, marks with ``add_mark`` (or poses up front); take
    estimates with ``poll`` as they become available and the rest with ``finish``."""

    def __init__(self, config: PipelineConfig, poses: Iterable[Pose] = (),
                 points_frame: PointsFrame | None = None,
                 gyr_bias_priors: Mapping[str, Sequence[float]] | None = None):
        """``gyr_bias_priors``: sensor name → the gyroscope bias its filter starts from
        [rad/s] (sensor frame), the kit's last learnt ones (``learnt_biases``); sensors the
        session does not wear are ignored."""
        self.config = config
        priors = gyr_bias_priors or {}
        self._tracks = {s: SensorTrack(s, config.filter, _prior(priors.get(s)),
                                       config.gyro_delay_s)
                        for s in config.sensors}
        self._reference = config.reference
        self._others = [t for n, t in self._tracks.items() if n != self._reference]
        self._poses = list(poses)
        self._marks: list[Mark] = []
        self._joints = CompiledJoints(config.side, config.lengths, config.joint_params)
        self._given = 0  # reference samples estimated so far
        self._given_t = -np.inf  # the last estimate's time [s]
        #: sensors left out live after they stopped sending (``stop_sensor``): name → the
        #: time of their last sample [s]
        self.stopped: dict[str, float] = {}
        self._unknown = np.zeros(len(REPORTED_ANGLES), dtype=bool)  # angles they leave unknown
        self._unknown_points = np.zeros(len(POINTS), dtype=bool)
        self._unknown_segments = np.zeros(len(SEGMENTS), dtype=bool)
        self.calibration: Calibration | None = None
        self._finished = False
        self._constraints: dict[str, HeadingConstraint] = {}
        self._mean_heading = False  # see ``_apply_constraints``
        self._turned: dict[int, np.ndarray] = {}  # segment → angle turned so far [rad]
        # the trunk's up direction over the session, to tell the lean's σ again at the
        # end (``sway.retold_lean``)
        self._sway = SwayBlocks() if "trunk" in config.sensors else None
        # wrist points (a robot's handle, a camera) and an upper-arm IMU: the γ elbow
        self._wrist: WristTrack | None = None
        self.gamma: GammaElbow | None = None
        if points_frame is not None and "upper_arm" in config.sensors:
            self._wrist = WristTrack(points_frame, config.side, config.lengths)
            self.gamma = GammaElbow(config.lengths, forearm_imu="forearm" in config.sensors)

    @property
    def elbow_source(self) -> str:
        """What makes the elbow: ``imu`` or ``points`` (the γ elbow from wrist points)."""
        return self.gamma.source if self.gamma is not None else "imu"

    def feed_points(self, point: str, t, p) -> None:
        """Positions of a point (``wrist``) at times ``t`` [s] (N,), ``p`` [m] (N, 3) in the
        session's points frame, in time order. Ignored without an upper-arm IMU (the γ
        elbow needs one)."""
        if self._finished:
            raise InvalidArgument("the pipeline was finished; start a new one")
        if point != "wrist":
            raise InvalidArgument(f"unknown point {point!r} (the pipeline uses 'wrist')")
        if self._wrist is not None:
            self._wrist.append(t, p)

    def add_mark(self, mark: Mark) -> None:
        """A stream's mark; calibration poses are taken from ``npose``/``tpose`` marks."""
        if self.calibration is None:
            self._marks.append(mark)

    def feed(self, sensor: str, t, acc, gyr, mag=None) -> None:
        """Samples of one sensor (t [s] (N,), acc [m/s²], gyr [rad/s], mag [µT] or None)."""
        if self._finished:
            raise InvalidArgument("the pipeline was finished; start a new one")
        if sensor not in self._tracks:
            raise InvalidArgument(f"sensor {sensor!r} is not in this session "
                                  f"({', '.join(self._tracks)})")
        self._tracks[sensor].append(t, acc, gyr, mag)
        if sensor == "trunk" and self._sway is not None:
            self._sway.add(np.column_stack([np.asarray(t, dtype=np.float64),
                                            np.asarray(acc, dtype=np.float64)]))

    def feed_rows(self, sensor: str, rows: np.ndarray) -> None:
        """``feed`` of stream rows (n, 10) float64 ``[t, ax, ay, az, gx, gy, gz, mx, my,
        mz]``, NaN magnetometer on a 6-axis sensor (the live server's messages): the same
        estimates as ``feed`` of the columns, in fewer calls."""
        if self._finished:
            raise InvalidArgument("the pipeline was finished; start a new one")
        track = self._tracks.get(sensor)
        if track is None:
            raise InvalidArgument(f"sensor {sensor!r} is not in this session "
                                  f"({', '.join(self._tracks)})")
        track.append_rows(rows)
        if sensor == "trunk" and self._sway is not None:
            self._sway.add(rows)

    def learnt_biases(self) -> dict[str, LearntGyroBias]:
        """Each sensor's gyroscope bias after its last sample and how it was learnt (see
        ``LearntGyroBias``: only a ``remembered`` one is for the kit's next session), for
        the sensors with samples whose filter reports one (``qcf``)."""
        out = {}
        for name, track in self._tracks.items():
            learnt = getattr(track.filter, "learnt_bias", None)
            value = learnt() if learnt is not None else None
            if value is not None:
                out[name] = value
        return out

    def silent_sensors(self) -> list[str]:
        """Sensors of the session that have not sent a sample yet."""
        return [name for name, track in self._tracks.items() if track.first_t == np.inf]

    def drop_sensor(self, sensor: str) -> None:
        """Leave out a sensor that never sent a sample (a node that failed to start), so
        the others need not wait for it. Refused once it has data or estimates began."""
        track = self._tracks.get(sensor)
        if track is None or track.first_t < np.inf or self._given:
            raise InvalidArgument(f"sensor {sensor!r} cannot be dropped: only a sensor of "
                                  "the session with no samples, before estimates begin")
        if len(self._tracks) == 1:
            raise InvalidArgument("the last sensor of a session cannot be dropped")
        del self._tracks[sensor]
        self.config = replace(self.config, sensors=tuple(self._tracks))
        self._reference = self.config.reference
        self._others = [t for n, t in self._tracks.items() if n != self._reference]

    def last_times(self) -> dict[str, float]:
        """Each sensor's last sample time [s] (-inf: none yet), of the sensors still in."""
        return {name: track.last_t for name, track in self._tracks.items()}

    def held_rows(self) -> int:
        """Samples the tracks hold (waiting for the others, or for slerp)."""
        return sum(track.kept() for track in self._tracks.values())

    def stop_sensor(self, sensor: str) -> EstimateArrays | None:
        """Leave out a sensor that stopped sending while the others go on (a node's battery
        died, its link dropped), so the others need not wait for it: a live decision, never
        made on a file (``armtrack estimate`` gives what it always gave). Before
        calibration it is as if it had never been worn (as ``drop_sensor``, data or not),
        but for what it leaves unknown (below). After, the estimates that waited for its
        samples are given now (returned, None if none). From then on its segment moves
        with its parent and is unknown (NaN in ``R_world_segment``), as are the angles it
        measures and those of the next sensor down the arm (measured against it), and the
        points from its segment's end on.
        Refused for the last sensor, or one not in the session."""
        track = self._tracks.get(sensor)
        if track is None:
            raise InvalidArgument(f"sensor {sensor!r} cannot be stopped: it is not in this "
                                  f"session ({', '.join(self._tracks)})")
        if len(self._tracks) == 1:
            raise InvalidArgument("the last sensor of a session cannot be stopped")
        waited = None
        if self.calibration is not None and not self._finished:
            waited = self._estimate(final=False)
        self.stopped[sensor] = track.last_t
        del self._tracks[sensor]
        self.config = replace(self.config, sensors=tuple(self._tracks))
        old = self._reference
        self._reference = self.config.reference
        self._others = [t for n, t in self._tracks.items() if n != self._reference]
        segment = _SEGMENT_INDEX[SEGMENT_OF_SENSOR[sensor]]
        below = next((s for s in SENSOR_NAMES[SENSOR_NAMES.index(sensor) + 1:]  # down the arm
                      if s in self._tracks), None)
        for name in (sensor, below):
            for angle in ANGLES_OF_SENSOR.get(name or "", ()):
                self._unknown[REPORTED_ANGLES.index(angle)] = True
        if segment > 0:  # the thorax held where calibration put it keeps the points
            self._unknown_segments[segment] = True
            self._unknown_points[segment - 1:] = True
        if self.calibration is None:
            return None
        if self._reference != old:  # estimates go on at the new reference's sample times
            reference = self._tracks[self._reference]
            self._given = reference.discarded + int(
                reference.times().searchsorted(self._given_t, "right"))
        self._constraints.pop(sensor, None)
        if sensor == "upper_arm":  # the elbow's tie needs the upper arm
            self._constraints.pop("forearm", None)
        return waited

    def poll(self) -> Estimates:
        """Every estimate that has become available since the last call."""
        return self._advance(final=False)

    def poll_arrays(self) -> EstimateArrays | None:
        """``poll`` as the kernels' arrays (None when nothing is new): the same numbers
        without a view per angle, point and segment (the live server's every message)."""
        if not self._calibrated(final=False):
            return None
        return self._estimate(final=False)

    def finish(self) -> Estimates:
        """The end of the stream: calibrate if not yet done, and estimate the rest; the
        calibration's lean σ and its warning are then told again by how the trunk swayed
        through the session (``sway.retold_lean``)."""
        self._finished = True
        estimates = self._advance(final=True)
        if self.calibration is not None and self._sway is not None:
            self.calibration = retold_lean(self.calibration, *self._sway.blocks())
        return estimates

    # -- internals ---------------------------------------------------------------------
    def _plan(self) -> CalibrationPlan:
        return CalibrationPlan.from_poses([*self._poses, *poses_from_marks(self._marks)])

    def _advance(self, final: bool) -> Estimates:
        if not self._calibrated(final):
            return Estimates.empty()
        arrays = self._estimate(final)
        return Estimates.empty() if arrays is None else arrays.named()

    def _calibrated(self, final: bool) -> bool:
        """Whether calibration is done, doing it once its poses have passed (or at the
        end of the stream)."""
        if self.calibration is not None:
            return True
        tracks = [t for t in self._tracks.values() if t.first_t < np.inf]
        if not tracks or self._tracks[self._reference].last_t == -np.inf:
            return False
        plan = self._plan()
        first = min(t.first_t for t in tracks)
        final_time = plan.final_time(first)
        passed = all(t.last_t >= final_time for t in self._tracks.values())
        if not (passed or final):
            return False
        present = {name: track for name, track in self._tracks.items()
                   if track.first_t < np.inf}
        field_warning = None
        if all(track.nine_axis for track in present.values()):
            if plan.method == "default":  # the first second stands in for the N-pose
                poses = [(first, first + 1.0)]
            else:
                poses = [(p.start, p.end) for p in (plan.npose, plan.tpose) if p is not None]
            disagreeing = disagreeing_sensors(present, final_time, poses)
            if disagreeing:
                # the kit's magnetometers see different fields: one heading for all comes
                # from the calibration and the joints instead (see ``magnetic``)
                for track in present.values():
                    track.drop_magnetometer()
                field_warning = disagreement_warning(disagreeing, list(present))
        trunk = present.get("trunk")
        if trunk is not None:
            # a trunk that only sways never shows its vertical bias to the tilt, and an
            # arm that never rests shows its biases only slowly to its tilt windows (its
            # own accelerations hide them): the held poses' gyroscopes give them
            # (``biases_from_poses``), and each filter is restarted knowing them that well
            # (else the first tilt window that sees the trunk's horizontal part learnt hands
            # its model error to the barely seen vertical one: 1–4 mrad/s off, sine sway
            # seed 2 −0.5 → −4.3 mrad/s at 20 s). The trunk's whole bias, not its vertical
            # part alone: a horizontal bias left to the tilt windows is learnt again
            # through the N-pose, whose trunk orientation the calibration takes (9-axis
            # random sway seed 1 with a 15-s N-pose: 11.9 mrad/s, side lean −0.31° from
            # the sway's centre, −0.55° as calibrated). A 9-axis trunk too: its first heading
            # windows take the tilt warm-up's turn of the field for a vertical bias (4.9–6.3
            # mrad/s off at 10.5 s on random sway seeds 4/7/8), which the poses' prior
            # holds off. A 9-axis arm sensor too: its heading windows take the sway for a
            # vertical bias alike, and the thorax's turn about its long axis comes from the
            # arm's heading over the N-pose (a 15-s N-pose: upper arm −4.1° off at 14 s,
            # random sway seed 15; the 3-s kits' held-out 22 → 25 of 30 within the bars).
            # An arm sensor that stillness taught its bias by the poses' end keeps its
            # filter, unless the poses contradict that bias beyond chance
            # (``stillness_contradicted``): then the stillness was a slow turn (a sway
            # from the first sample that qcf's still start took for stillness over half
            # a second: random sway seed 13 with a 15-s N-pose, upper arm 42 mrad/s off,
            # elbow flexion 7.20°).
            found = biases_from_poses(present, plan, {
                name: _old_prior(track) for name, track in present.items()})
            if found is not None:
                spread = QcfParams().bias_sigma
                bias, covariance = found.trunk
                trunk.restart_filter(_triple(bias), _bounded(covariance, spread))
                for sensor, (bias, covariance) in found.arm.items():
                    track = present[sensor]
                    if stillness_contradicted(track.stillness_bias(final_time), bias,
                                              covariance):
                        track.restart_filter(_triple(bias), _bounded(covariance, spread))
        self.calibration = calibrate(present, plan, self.config.side, final_time)
        for track in self._tracks.values():
            track.forget_magnetometer()
        if field_warning is not None:
            self.calibration = replace(self.calibration, warnings=(
                *self.calibration.warnings, field_warning))
        # Every kit: the forearm's and hand's headings are tied by the joints (6-axis
        # sensors drift apart; 9-axis ones see fields that differ from sensor to sensor
        # near metal): the magnetometer is evidence, the joints decide.
        # The elbow also follows how fast its sensors' headings drift apart (the difference
        # of their unlearnt vertical biases) where one of them has its heading from the
        # gyroscope alone and no stillness up to the poses' end taught it its bias (a
        # swaying kit: nothing ever rests); a magnetometer's heading does not drift, and a
        # bias a rest or a still start taught drifts only by its walk (RING's chain: the
        # rate cost its foam-mounted trial 2 up to 0.8° at the wrist). The wrist keeps the
        # mean: fitted there too, the rate made 11 of 12 swaying kits worse.
        def drifts(sensor: str) -> bool:
            track = present.get(sensor)
            return track is not None and not (
                track.nine_axis and not track.magnetometer_dropped) and not \
                track.still_taught(final_time)
        elbow_rate = DRIFT_RATE_PRIOR if drifts("forearm") or \
            drifts("upper_arm") else math.inf
        self._constraints = {s: HeadingConstraint(rate_prior=elbow_rate if s == "forearm"
                                                  else math.inf)
                             for s in ("forearm", "hand") if s in present}
        # headings from the gyroscopes alone, and no wrist points to hold the upper arm's
        self._mean_heading = self.gamma is None and not all(
            track.nine_axis and not track.magnetometer_dropped for track in present.values())
        if "forearm" in present and "upper_arm" not in present:
            # against the virtual upper arm hanging still (see ``_apply_constraints``)
            self._constraints["forearm"] = HeadingConstraint(
                gate=VIRTUAL_HINGE_GATE,
                rate_prior=elbow_rate)
        return True

    def _estimate(self, final: bool) -> EstimateArrays | None:
        assert self.calibration is not None
        reference = self._tracks[self._reference]
        t_ref = reference.times()
        horizon = np.inf
        if not final:
            for track in self._others:
                if track.last_t < horizon:
                    horizon = track.last_t
            if self._wrist is not None:  # wait for the points, but not for ever
                waited = max(self._wrist.last_t, reference.last_t - MAX_POINTS_LAG_S)
                horizon = min(horizon, waited)
        start = self._given - reference.discarded
        stop = int(t_ref.searchsorted(horizon, "right")) if math.isfinite(horizon) \
            else len(t_ref)
        if stop <= start:
            return None
        times = t_ref[start:stop].copy()
        self._given += stop - start

        n = len(times)
        Rw = np.empty((n, 5, 3, 3))  # R_world_segment in SEGMENTS order
        present = np.zeros(5)
        taken: dict[int, np.ndarray] = {}  # segment → heading drift taken back [rad]
        knots: dict[int, np.ndarray] = {}  # segment → its gap's start [s] (``drift``)
        for name, track in self._tracks.items():
            if track.first_t == np.inf:
                continue
            index = _SEGMENT_INDEX[SEGMENT_OF_SENSOR[name]]
            t, q = track.times(), track.orientations()
            segment_orientations(t, q, times, self.calibration.R_sensor_segment[name],
                                 self.calibration.heading[name], out=Rw[:, index])
            present[index] = 1.0
            if track.nine_axis is False and self.gamma is None:  # points hold the heading
                # each sensor's own drift taken back turns its segment now, before the
                # joints tie them (no γ elbow here: it would come before the turn)
                drift = np.empty((n, 2))
                taken_at(t, track.drift_taken_back(), times, Rw[:, index], drift)
                taken[index], knots[index] = drift[:, 0], drift[:, 1]
        if not present[0]:  # no trunk sensor (or it stopped): the thorax stays where
            # calibration put it
            Rw[:, 0] = self.calibration.R_world_thorax
            present[0] = 1.0
        points_flexion = None
        if self.gamma is not None and self._wrist is not None:
            points_flexion, flagged = self.gamma.apply(
                Rw, present, self._wrist.at(times), self._wrist.shoulder_thorax,
                _SEGMENT_INDEX["upper_arm"], _SEGMENT_INDEX["forearm"])
        if self._constraints:
            self._apply_constraints(times, Rw, present, taken, knots)
        angles, residuals, positions, R_world_all = self._joints.update(Rw, present)
        if points_flexion is not None and self.gamma is not None and self.gamma.forearm_imu:
            self.gamma.compare(points_flexion, angles[:, _ELBOW_FLEXION], flagged)
        if self.stopped:  # unknown without a stopped sensor (``stop_sensor``)
            angles[:, self._unknown] = np.nan
            positions[:, self._unknown_points] = np.nan
            R_world_all[:, self._unknown_segments] = np.nan
        # no later estimate looks further back than this one: the tracks forget the rest
        last = float(times[-1])
        self._given_t = last
        for track in self._tracks.values():
            track.discard_before(last)
        if self._wrist is not None:
            self._wrist.discard_before(last)
        return EstimateArrays(times, angles, residuals, positions, R_world_all)

    def _apply_constraints(self, times: np.ndarray, Rw: np.ndarray, present: np.ndarray,
                           taken: dict[int, np.ndarray], knots: dict[int, np.ndarray]
                           ) -> None:
        """Turn the forearm and hand about the vertical by their joints' heading error.
        (A left arm's medial Z flips ``u·v`` and ``D`` alike: the estimate is the same.)
        Without an upper-arm sensor the upper arm hangs still from its parent (the stated
        assumption of a forearm-only kit, ``metrics.assumptions``): the elbow's hinge
        against that virtual upper arm ties the forearm's heading all the same.

        The joints tie the arm's sensors' headings to one another, not to the world: where
        they come from the gyroscopes alone (6-axis, or the kit's magnetometers left out)
        each sensor's heading drifts on its own (unless wrist points hold the upper arm's:
        the γ elbow), so the chain is then turned as a whole to
        the mean of its sensors' own headings (the mean of independent drifts: up to √3
        smaller with three sensors) rather than left on the upper arm's alone, each weighed
        by ``1 / (MEAN_HEADING_FLOOR_RAD + the angle it has turned)``: a resting sensor's
        heading holds (an elbow exercise's still upper arm keeps the arm's heading).

        ``taken`` (segment → [rad] at ``times``) is each 6-axis sensor's heading drift taken
        back at its rests (``drift``), which has already turned its segment, and ``knots``
        the time [s] its gap counts from: each joint turns what it remembers by the part of
        a step that came before each remembered sample (``_constrain``), so where the joint
        was seen bent through the gap its tie holds, and where it was straight (blind)
        since before the gap the sensors' own headings, taken back, hold."""
        forearm, hand = _SEGMENT_INDEX["forearm"], _SEGMENT_INDEX["hand"]
        upper_arm = next(s for s in (_SEGMENT_INDEX["upper_arm"], _SEGMENT_INDEX["clavicle"],
                                     _SEGMENT_INDEX["thorax"]) if present[s])
        pairs = {"forearm": (upper_arm, forearm, 2, 1),
                 "hand": (forearm, hand, 0, 2)}
        mean = self._mean_heading and upper_arm == _SEGMENT_INDEX["upper_arm"]
        chain, offsets = [upper_arm], []
        for segment, constraint in self._constraints.items():
            parent, child, u_axis, v_axis = pairs[segment]
            if not present[parent]:
                continue
            turned = (child,)
            if segment == "forearm" and present[hand] and "hand" not in self._constraints:
                turned = (forearm, hand)
            steps = gaps = None  # the drift taken back from child and parent [rad]
            if child in taken or parent in taken:
                steps, gaps = np.zeros((len(times), 2)), np.full((len(times), 2), np.nan)
                for j, segment in enumerate((child, parent)):
                    if segment in taken:
                        steps[:, j], gaps[:, j] = taken[segment], knots[segment]
            delta = constraint.apply(times, Rw, parent, child, u_axis, v_axis, turned,
                                     steps, gaps)
            if mean and parent in chain:
                chain.append(child)
                offsets.append(delta)  # the child's own heading is the chain's − delta
        if len(chain) > 1:
            turned = np.empty((len(chain), len(times)))
            own = np.empty((len(chain), len(times)))  # chain's − own heading [rad]
            for j, segment in enumerate(chain):
                t, _, gyr, _ = self._tracks[_SENSOR_OF_SEGMENT[segment]].arrays()
                turned_angle(t, gyr, times, self._turned.setdefault(segment, np.zeros(1)),
                             turned[j])
                own[j] = offsets[j - 1] if j else 0.0
            mean_turn(Rw, np.array(chain, dtype=np.int64), own, turned,
                      MEAN_HEADING_FLOOR_RAD)


def stillness_contradicted(taught: tuple[np.ndarray, np.ndarray] | None, bias: np.ndarray,
                           covariance: np.ndarray) -> bool:
    """Whether a filter's bias is not one stillness taught (``taught`` None), or one the
    held poses' ``bias`` [rad/s] with its ``covariance`` [rad²/s²] contradicts: their
    difference's squared Mahalanobis norm under both covariances beyond
    ``STILLNESS_CONTRADICTED``. A stillness from the first sample is judged over half a
    second, where a slow turn (a sway at 0.04 rad/s) tilts the accelerometer by less than
    its noise; the poses see seconds of it."""
    if taught is None:
        return True
    learnt, learnt_covariance = taught
    difference = learnt - bias
    total = covariance + learnt_covariance
    return float(difference @ np.linalg.solve(total, difference)) > STILLNESS_CONTRADICTED


def _old_prior(track: SensorTrack) -> np.ndarray:
    """The gyroscope bias a track's filter started from [rad/s] (zeros: none)."""
    return np.zeros(3) if track.gyr_bias_prior is None else \
        np.asarray(track.gyr_bias_prior, dtype=np.float64)


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _bounded(covariance: np.ndarray, spread: float) -> tuple[tuple[float, ...], ...]:
    """A bias prior's covariance [rad²/s²] as the filter takes it: symmetric, each axis's
    variance within (0, ``spread``²] (a least squares' own is within it but for rounding)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    values = np.clip(values, spread**2 * 1e-8, spread**2)
    bounded = (vectors * values) @ vectors.T
    bounded = 0.5 * (bounded + bounded.T)
    return tuple(tuple(float(v) for v in row) for row in bounded)


def _prior(value: Sequence[float] | None) -> tuple[float, float, float] | None:
    if value is None:
        return None
    try:
        values = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = np.empty(0)
    if values.shape != (3,):
        raise InvalidArgument(f"a gyroscope bias prior must be 3 numbers [rad/s], got {value!r}")
    return float(values[0]), float(values[1]), float(values[2])


_SEGMENT_INDEX = {segment: i for i, segment in enumerate(SEGMENTS)}
_SENSOR_OF_SEGMENT = {_SEGMENT_INDEX[segment]: sensor
                      for sensor, segment in SEGMENT_OF_SENSOR.items()}
#: The mean heading's weights: a sensor's heading drifts while it moves (at rest the filter
#: holds it and learns the bias), so its drift is taken to grow with the angle it has
#: turned, and its weight is 1 / (this + that angle) [rad].
MEAN_HEADING_FLOOR_RAD = 1.0
#: The squared Mahalanobis norm beyond which the held poses contradict a bias stillness
#: taught (``stillness_contradicted``): chi-square's 99.9 % point on 3 degrees of freedom.
#: Measured: a rest's bias against the poses' on still-trunk kits (seeds 1–20, 6- and
#: 9-axis, every arm sensor) 0.0–1.8; the slow turn random sway seed 13's still start
#: took, tens of thousands.
STILLNESS_CONTRADICTED = 16.27
#: A forearm-only kit's elbow hinge against the virtual upper arm: the largest residual
#: (the sine of the forearm's turn out of the hinge's plane) a sample may show and count.
#: A 6-axis heading drift shows a few degrees at most; an arm raised shows tens.
VIRTUAL_HINGE_GATE = math.sin(math.radians(8.0))
_ELBOW_FLEXION = REPORTED_ANGLES.index("elbow_flexion")
