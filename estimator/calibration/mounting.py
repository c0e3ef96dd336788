"""Sensor-to-segment rotations ``R_sensor_segment`` from the calibration poses.

* Two poses (N-pose and T-pose): for an arm segment, gravity gives the segment's +Y in
  the sensor frame in the N-pose (the arm hangs: +Y, proximal, is up) and its ±Z in the
  T-pose (abduction 90°: +Z is up on a right arm, −Z on a left one, whose Z points
  medially). Two directions fix the rotation whole (Wahba's problem, solved by
  ``scipy``'s ``align_vectors``).
* N-pose only: gravity gives +Y; the rotation about it is taken from the default mounting
  (``docs/spec/recording.md``): the smallest turn of the default that agrees with gravity.
* Trunk and clavicle do not move between the poses: gravity gives their tilt, and their
  heading comes from the arm — in the N-pose every segment's axes are the thorax's, so
  ``R_world_thorax = R_world_upper_arm`` there (``heading_from_arm``).
* No pose: the default mounting whole.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..body import Side
from ..errors import InvalidArgument

ARM_SENSORS = ("upper_arm", "forearm", "hand")


def default_R_segment_sensor(sensor: str, side: Side) -> np.ndarray:
    """``R_segment_sensor`` of the default mounting (``docs/spec/recording.md``)."""
    turn = np.diag([-1.0, 1.0, -1.0]) if side == "left" else np.eye(3)  # 180° about Y
    if sensor in (*ARM_SENSORS, "clavicle"):
        return turn
    if sensor == "trunk":
        # On the sternum: +Y up, +Z out of the skin (anterior), +X = Y × Z to the left.
        return np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    raise InvalidArgument(f"unknown sensor {sensor!r}")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def two_pose_R_sensor_segment(up_npose: np.ndarray, up_tpose: np.ndarray, side: Side,
                              npose_weight: float = 1.0) -> np.ndarray:
    """``R_sensor_segment`` of an arm sensor from the measured up directions (sensor frame)
    in the N-pose (segment +Y) and the T-pose (segment ±Z)."""
    up_z = 1.0 if side == "right" else -1.0
    segment_dirs = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, up_z]])
    sensor_dirs = np.array([_unit(up_npose), _unit(up_tpose)])
    rotation, _ = Rotation.align_vectors(sensor_dirs, segment_dirs,
                                         weights=[npose_weight, 1.0])
    return rotation.as_matrix()


def tilt_only_R_sensor_segment(up_npose: np.ndarray, sensor: str, side: Side,
                               segment_up: np.ndarray | None = None) -> np.ndarray:
    """The default ``R_sensor_segment`` turned by the smallest rotation that makes the
    segment's up direction in the N-pose (``segment_up``, default +Y) match gravity."""
    segment_up = np.array([0.0, 1.0, 0.0]) if segment_up is None else segment_up
    R_sensor_segment = default_R_segment_sensor(sensor, side).T
    predicted = R_sensor_segment @ segment_up
    turn, _ = Rotation.align_vectors(_unit(up_npose)[None], predicted[None])
    return turn.as_matrix() @ R_sensor_segment


def heading_from_arm(R_world_sensor_npose: np.ndarray, R_world_thorax_npose: np.ndarray
                     ) -> np.ndarray:
    """``R_sensor_segment`` of a trunk or clavicle sensor: in the N-pose its segment's axes
    are the thorax's, known from the arm."""
    return R_world_sensor_npose.T @ R_world_thorax_npose
