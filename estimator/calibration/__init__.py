"""Calibration: the poses, sensor-to-segment rotations and their quality."""

from .magnetometer import SphereFit, minmax_offset, sphere_fit_offset
from .mounting import (
    default_R_segment_sensor,
    heading_from_arm,
    tilt_only_R_sensor_segment,
    two_pose_R_sensor_segment,
)
from .plan import CalibrationPlan, poses_from_marks
from .quality import CalibrationWarning, pose_stillness_warnings, stillness_warning, turn_warning

__all__ = [
    "CalibrationPlan",
    "CalibrationWarning",
    "SphereFit",
    "default_R_segment_sensor",
    "heading_from_arm",
    "minmax_offset",
    "pose_stillness_warnings",
    "poses_from_marks",
    "sphere_fit_offset",
    "stillness_warning",
    "tilt_only_R_sensor_segment",
    "turn_warning",
    "two_pose_R_sensor_segment",
]
