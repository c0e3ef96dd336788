"""Calibration of a session from its sensors' tracks: sensor-to-segment rotations, the
thorax's heading, and (6-axis kits) the headings that put every sensor in one world.

Order: arm sensors first (two-pose, N-pose-only or default mounting; with a trunk sensor
on a 9-axis kit, each pose's up direction is the thorax's, not gravity's, so a trunk that
sways through the poses does not tilt the arm's axes by the sway's mean, and the thorax's
upright, the trunk's mean over the poses, is made square to the axis the arm turned about
between them relative to the trunk, so a slow sway's lean left in that mean does not turn
the arm's axes about the vertical); then the world
thorax in the N-pose from the arm (every segment's axes are the thorax's there); then the
trunk and clavicle sensors' headings from it. On a 6-axis kit each sensor's filter has a
heading of its own: in the N-pose all segments point the same way, which gives each
sensor the turn about the vertical that brings it into the reference sensor's world; there
a trunk or clavicle sensor's own turn about the vertical is the default mounting's (no
shared heading makes it observable), so the thorax is right in the N-pose and a trunk
sensor mounted turned on the sternum mixes forward and sideways bending by that turn.
With no pose at all (default mounting) the first second of the recording stands in for
the N-pose: the patient is taken to start with the arm hanging.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..body import Side
from ..calibration import (
    CalibrationPlan,
    CalibrationWarning,
    default_R_segment_sensor,
    heading_from_arm,
    pose_stillness_warnings,
    tilt_only_R_sensor_segment,
    turn_warning,
    two_pose_R_sensor_segment,
)
from ..calibration.quality import TPOSE_TURN_DEG
from ..rotations import quat_to_matrix, yaw_of
from .segment_kernel import segment_orientations
from .tracks import SensorTrack

ARM = ("upper_arm", "forearm", "hand")
#: How well the arm's turn between the poses, relative to the trunk sensor, gives the
#: thorax's X (9-axis filters' relative heading over the poses; a still trunk: 0.3–0.4°).
AXIS_SIGMA_RAD = np.deg2rad(0.5)


@dataclass(frozen=True)
class Calibration:
    """The result: ``method`` (two-pose, n-pose, default), ``final_time_s``;
    ``R_sensor_segment`` per sensor; ``heading`` per sensor [rad], the turn about the
    vertical applied to its world (0 with a magnetometer); ``R_world_thorax`` the fixed
    thorax when there is no trunk sensor; ``warnings``. A segment's orientation is
    ``Rz(heading) · R_world_sensor · R_sensor_segment`` (``segment_kernel``)."""

    method: str
    final_time_s: float
    R_sensor_segment: dict[str, np.ndarray]
    heading: dict[str, float]
    R_world_thorax: np.ndarray
    warnings: tuple[CalibrationWarning, ...]


def _up(acc: np.ndarray) -> np.ndarray:
    mean = acc.mean(axis=0)
    return mean / np.linalg.norm(mean)


def _mean_rotation(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q, scalar_first=True).mean().as_matrix()


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _thorax_up(arm: SensorTrack, trunk: SensorTrack, start: float, end: float,
               trunk_up: np.ndarray) -> np.ndarray:
    """The thorax's up direction in an arm sensor's frame over ``start…end``, averaged:
    the arm's gravity plus the trunk's momentary tilt away from its upright ``trunk_up``
    (trunk sensor frame), carried into the arm sensor's frame through the two sensors'
    orientations at the arm's sample times. Both directions are the accelerometers';
    the orientations only turn the small tilt, so their errors count to second order."""
    t, acc, _, q = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t, acc, q = t[a:b], acc[a:b], q[a:b]
    t_trunk, acc_trunk, _, q_trunk = trunk.arrays()
    gravity_trunk = _unit_rows(np.stack([np.interp(t, t_trunk, acc_trunk[:, k])
                                         for k in range(3)], axis=1))
    R_trunk = segment_orientations(t_trunk, q_trunk, t, np.eye(3), 0.0)
    tilt_world = np.einsum("nij,nj->ni", R_trunk, trunk_up - gravity_trunk)
    tilt_arm = np.einsum("nji,nj->ni", quat_to_matrix(q), tilt_world)
    return _up(_unit_rows(acc) + tilt_arm)


def _relative(arm: SensorTrack, trunk: SensorTrack, start: float, end: float
              ) -> np.ndarray | None:
    """The arm sensor's axes in the trunk sensor's frame, ``R_trunk_arm``, averaged over
    ``start…end`` at the arm's sample times (None without samples): a sway that turns
    both sensors alike drops out."""
    t, _, _, q = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t_trunk, _, _, q_trunk = trunk.arrays()
    if b <= a or not len(t_trunk):
        return None
    R_trunk = segment_orientations(t_trunk, q_trunk, t[a:b], np.eye(3), 0.0)
    return Rotation.from_matrix(np.einsum("nji,njk->nik", R_trunk, quat_to_matrix(q[a:b]))
                                ).mean().as_matrix()


def _abduction_axis(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan
                    ) -> np.ndarray | None:
    """The axis (unit, trunk sensor frame) about which the arm turned from the N-pose to
    the T-pose relative to the trunk sensor, mean over the arm's sensors: the thorax's X.
    None when a window is empty or an arm sensor did not turn like a T-pose."""
    assert plan.npose is not None and plan.tpose is not None
    axes = []
    for sensor in (s for s in ARM if s in tracks):
        n = _relative(tracks[sensor], tracks["trunk"], plan.npose.start, plan.npose.end)
        t = _relative(tracks[sensor], tracks["trunk"], plan.tpose.start, plan.tpose.end)
        if n is None or t is None:
            return None
        turn = Rotation.from_matrix(t @ n.T).as_rotvec()
        angle = np.linalg.norm(turn)
        lo, hi = TPOSE_TURN_DEG
        if not lo <= np.rad2deg(angle) <= hi:
            return None
        axis = turn / angle
        axes.append(axis if not axes or axis @ axes[0] > 0 else -axis)
    if not axes:
        return None
    mean = np.mean(axes, axis=0)
    return mean / np.linalg.norm(mean)


def _sway_range(trunk: SensorTrack, start: float, end: float, axis: np.ndarray) -> float:
    """How far the trunk's up direction (its filter's tilt, trunk sensor frame) moved
    along ``axis`` over ``start…end``: max − min [rad, small angles]."""
    _, _, q = trunk.window(start, end)
    along = quat_to_matrix(q)[:, 2, :] @ axis  # world z in the sensor frame, along axis
    return float(along.max() - along.min()) if len(along) else 0.0


def calibrate(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan, side: Side,
              final_time_s: float) -> Calibration:
    """Calibrate from the tracks (each holding at least the data up to ``final_time_s``)."""
    warnings: list[CalibrationWarning] = []
    method = plan.method
    windows = {}
    labels = {"npose": "N-pose", "tpose": "T-pose"}
    for pose in (plan.npose, plan.tpose):
        if pose is None:
            continue
        for sensor, track in tracks.items():
            windows[sensor, pose.name] = track.window(pose.start, pose.end)
        warnings += pose_stillness_warnings(labels[pose.name], {
            sensor: windows[sensor, pose.name][1::-1] for sensor in tracks})
    empty = sorted({pose for (_, pose), (acc, _, _) in windows.items() if len(acc) < 2})
    if method != "default" and empty:
        method = "default"
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            f"the {', '.join(labels[p] for p in empty)} window holds no samples of some "
            f"sensor: the sensors are taken to sit as the kit's guide shows them; redo the "
            f"poses with every sensor on for exact angles"))
    elif method == "default":
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            "no calibration pose: the sensors are taken to sit as the kit's guide shows "
            "them and the arm to hang straight at the start; angles may be off by how far "
            "they do not. Start the next session with the N-pose and T-pose"))

    nine_axis = all(track.nine_axis and not track.magnetometer_dropped
                    for track in tracks.values())
    # A trunk that sways through the poses tilts the whole body with it: an arm sensor's
    # gravity then gives its segment's axes off by the sway's mean over each pose. The
    # trunk sensor sees the sway; its upright is the mean of its up direction over both
    # poses and the time between (the trunk does not move between them; a sway's mean
    # over seconds is nearer upright than over one pose), and the arm takes the thorax's
    # up, not gravity's, carried through both sensors' orientations. Only where all
    # sensors share a heading (9-axis): the carried direction would otherwise turn by the
    # sensors' heading difference; and not when the trunk sensor turned like an arm
    # between the poses (then it is not on the trunk: see the turn warnings).
    sway_corrected = nine_axis and "trunk" in tracks and method != "default"
    if sway_corrected and method == "two-pose":
        sway_corrected = turn_warning("trunk", _up(windows["trunk", "npose"][0]),
                                      _up(windows["trunk", "tpose"][0])) is None
    if sway_corrected:
        span = [p for p in (plan.npose, plan.tpose) if p is not None]
        acc_trunk, _, _ = tracks["trunk"].window(min(p.start for p in span),
                                                 max(p.end for p in span))
        trunk_up = _up(_unit_rows(acc_trunk))
        # The mean keeps what a slow sway's partial cycles did not average out (~2° at
        # 0.1–0.2 Hz over these 7.5 s). Its part toward the thorax's X (a forward lean)
        # is what hurts: the T-pose turns the arm about X, so the two-direction arm
        # calibration makes that lean a turn about the vertical; a side lean (about X)
        # tilts every segment alike. The thorax's X is the axis the arm turned about
        # between the poses relative to the trunk sensor (a sway turns both alike), and the
        # upright is square to it. Weighed against the mean (Bayes): the mean's error is
        # within half the trunk's tilt range along X (a sway seen over half a cycle or
        # more), taken as 2σ; the axis's σ is AXIS_SIGMA_RAD; a still trunk keeps its mean.
        axis = _abduction_axis(tracks, plan) if method == "two-pose" else None
        if axis is not None:
            along = trunk_up @ axis
            sway = 0.25 * _sway_range(tracks["trunk"], min(p.start for p in span),
                                      max(p.end for p in span), axis)
            weight = sway**2 / (sway**2 + AXIS_SIGMA_RAD**2)
            trunk_up = trunk_up - weight * along * axis
            trunk_up /= np.linalg.norm(trunk_up)

    def pose_up(sensor: str, pose: str) -> np.ndarray:
        if sway_corrected and sensor in ARM:
            window = plan.npose if pose == "npose" else plan.tpose
            return _thorax_up(tracks[sensor], tracks["trunk"], window.start, window.end,
                              trunk_up)
        return _up(windows[sensor, pose][0])

    R_sensor_segment: dict[str, np.ndarray] = {}
    for sensor in tracks:
        if method == "default":
            R_sensor_segment[sensor] = default_R_segment_sensor(sensor, side).T
            continue
        up_n = pose_up(sensor, "npose")
        if sensor in ARM and method == "two-pose":
            up_t = pose_up(sensor, "tpose")
            R_sensor_segment[sensor] = two_pose_R_sensor_segment(up_n, up_t, side)
        else:
            R_sensor_segment[sensor] = tilt_only_R_sensor_segment(up_n, sensor, side)
        if method == "two-pose":  # how far gravity turned (not the sway-corrected up)
            warning = turn_warning(sensor, _up(windows[sensor, "npose"][0]),
                                   _up(windows[sensor, "tpose"][0]))
            if warning:
                warnings.append(warning)

    reference = next((s for s in ARM if s in tracks), next(iter(tracks)))
    heading = {sensor: 0.0 for sensor in tracks}

    def npose_segment(sensor: str) -> np.ndarray:
        if method == "default":
            t, _, _, q = tracks[sensor].arrays()
            q = q[: max(1, int(np.searchsorted(t, t[0] + 1.0)))]  # the first second
        else:
            q = windows[sensor, "npose"][2]
        return _mean_rotation(q) @ R_sensor_segment[sensor]

    R_world_thorax = npose_segment(reference) if reference in ARM else np.eye(3)
    for sensor in tracks:
        if not nine_axis and sensor != reference:
            # one world for all: the turn about the vertical that makes this segment point
            # where the reference's points in the N-pose
            heading[sensor] = float(yaw_of(npose_segment(reference)
                                           @ npose_segment(sensor).T))
        if sensor in ("trunk", "clavicle") and reference in ARM and method != "default":
            if nine_axis:
                # the magnetometer shares the heading: take it whole from the arm
                R_ws = _mean_rotation(windows[sensor, "npose"][2])
                R_sensor_segment[sensor] = heading_from_arm(R_ws, R_world_thorax)
    if "trunk" in tracks and reference not in ARM:
        R_world_thorax = npose_segment("trunk")
    return Calibration(method=method, final_time_s=final_time_s,
                       R_sensor_segment=R_sensor_segment, heading=heading,
                       R_world_thorax=R_world_thorax, warnings=tuple(warnings))


