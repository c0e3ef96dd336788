"""The arm model of ``docs/spec/kinematics.md``: forward kinematics, joint angles, seed DH
tables."""

from .dh import (
    DHMap,
    DHRow,
    dh_chain,
    dh_point_positions,
    dh_segment_orientations,
    paper_map,
    thesis_map,
)
from .forward import POINTS, ArmPose, forward_kinematics
from .gamma import GammaSolution, gamma_coefficients, gamma_roots, solve_gamma
from .inverse import JointAngleParams, JointAngles, JointAngleSolver, joint_angles
from .joints import (
    ANGLE_NAMES,
    ELEVATION,
    JOINTS,
    NORMAL_RANGE_DEG,
    PAPER_RANGE_DEG,
    REPORTED_ANGLES,
    SEGMENTS,
)

__all__ = [
    "ANGLE_NAMES", "ELEVATION", "JOINTS", "NORMAL_RANGE_DEG", "PAPER_RANGE_DEG", "POINTS",
    "REPORTED_ANGLES", "SEGMENTS", "ArmPose", "DHMap", "DHRow", "GammaSolution",
    "JointAngleParams",
    "JointAngleSolver", "JointAngles", "dh_chain", "dh_point_positions",
    "dh_segment_orientations", "forward_kinematics", "gamma_coefficients", "gamma_roots",
    "joint_angles", "paper_map", "solve_gamma", "thesis_map",
]
