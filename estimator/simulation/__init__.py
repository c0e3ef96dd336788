"""A simulator of IMU recordings with ground truth, after the thesis's App. B.2 but complete:
smooth joint profiles, exact IMU physics, mounting, noise, bias, jitter, lost samples."""

from .body_motion import BodyMotion, FrameMotion, PointMotion, Stance, body_motion
from .imu import Dipole, ImuErrors, MagneticEnvironment, Mount, default_mount, synthesize_imu
from .profiles import Excursion, Motion, Profile, Ramp, Sine, hold_and_return, repetitions
from .scenarios import EXERCISES, SCORED_FROM_S, calibration_sequence, exercise_motion
from .simulator import Simulation, SimulationConfig, Truth, simulate, write_truth

__all__ = [
    "EXERCISES", "SCORED_FROM_S", "BodyMotion", "Dipole", "Excursion", "FrameMotion", "ImuErrors",
    "MagneticEnvironment", "Motion", "Mount", "PointMotion", "Profile", "Ramp", "Simulation",
    "SimulationConfig", "Sine", "Stance", "Truth", "body_motion", "calibration_sequence",
    "default_mount", "exercise_motion", "hold_and_return", "repetitions", "simulate",
    "synthesize_imu", "write_truth",
]
