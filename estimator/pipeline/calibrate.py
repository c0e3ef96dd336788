"""Calibration of a session from its sensors' tracks: sensor-to-segment rotations, the
thorax's heading, and (6-axis kits) the headings that put every sensor in one world.

Order: arm sensors first (two-pose, N-pose-only or default mounting); then the world
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
    stillness_warning,
    tilt_only_R_sensor_segment,
    turn_warning,
    two_pose_R_sensor_segment,
)
from ..rotations import yaw_of
from .tracks import SensorTrack

ARM = ("upper_arm", "forearm", "hand")


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


def calibrate(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan, side: Side,
              final_time_s: float) -> Calibration:
    """Calibrate from the tracks (each holding at least the data up to ``final_time_s``)."""
    warnings: list[CalibrationWarning] = []
    method = plan.method
    windows = {}
    labels = {"npose": "N-pose", "tpose": "T-pose"}
    for sensor, track in tracks.items():
        for pose in (plan.npose, plan.tpose):
            if pose is None:
                continue
            acc, gyr, q = track.window(pose.start, pose.end)
            windows[sensor, pose.name] = (acc, gyr, q)
            warning = stillness_warning(labels[pose.name], sensor, gyr, acc)
            if warning:
                warnings.append(warning)
    empty = sorted({pose for (_, pose), (acc, _, _) in windows.items() if len(acc) < 2})
    if method != "default" and empty:
        method = "default"
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            f"the {', '.join(labels[p] for p in empty)} window holds no samples of some "
            f"sensor: the default mounting is assumed"))
    elif method == "default":
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            "no calibration pose: sensors are assumed in their default mounting "
            "(spec/recording.md); angles may be off by the mounting error"))

    R_sensor_segment: dict[str, np.ndarray] = {}
    for sensor in tracks:
        if method == "default":
            R_sensor_segment[sensor] = default_R_segment_sensor(sensor, side).T
            continue
        up_n = _up(windows[sensor, "npose"][0])
        if sensor in ARM and method == "two-pose":
            up_t = _up(windows[sensor, "tpose"][0])
            R_sensor_segment[sensor] = two_pose_R_sensor_segment(up_n, up_t, side)
        else:
            R_sensor_segment[sensor] = tilt_only_R_sensor_segment(up_n, sensor, side)
        if method == "two-pose":
            warning = turn_warning(sensor, up_n, _up(windows[sensor, "tpose"][0]))
            if warning:
                warnings.append(warning)

    nine_axis = all(track.nine_axis for track in tracks.values())
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


