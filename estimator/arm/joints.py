"""The joint chain of ``docs/spec/kinematics.md`` as data: names, axes, signs, normal ranges.

Right arm, intrinsic rotations composed left to right::

    R_thorax_clavicle   = Ry(clavicle_protraction) · Rx(-clavicle_elevation)
    R_clavicle_humerus  = Rz(shoulder_flexion) · Rx(-shoulder_abduction) · Ry(shoulder_rotation)
    R_humerus_forearm   = Rz(elbow_flexion) · Ry(forearm_pronation)
    R_forearm_hand      = Rx(wrist_flexion) · Rz(-wrist_deviation)

The left arm is the mirror image through the sagittal plane: ``R_left = M R_right M`` with
``M = diag(1, 1, -1)``, which flips the sign of every X and Y rotation and keeps Z.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Segments of the chain, proximal to distal. The thorax is the root.
SEGMENTS: tuple[str, ...] = ("thorax", "clavicle", "upper_arm", "forearm", "hand")

#: The sensor place on each segment (``docs/spec/recording.md``); only the thorax's differs.
SENSOR_OF_SEGMENT = {"thorax": "trunk", "clavicle": "clavicle", "upper_arm": "upper_arm",
                     "forearm": "forearm", "hand": "hand"}
SEGMENT_OF_SENSOR = {sensor: segment for segment, sensor in SENSOR_OF_SEGMENT.items()}


@dataclass(frozen=True)
class Joint:
    """One joint: ``R_parent_child = R_a(±q_a) · R_b(±q_b) · R_c(±q_c)`` (right arm).

    ``angles[i]`` names the joint angle about ``sequence[i]`` with sign ``signs[i]``;
    ``None`` marks an axis the joint does not have (its rotation there is a residual that an
    exact chain leaves at zero, reported by the inverse as ``residual``).
    """

    name: str
    parent: str
    child: str
    sequence: str
    angles: tuple[str | None, str | None, str | None]
    signs: tuple[int, int, int]
    residual: str


JOINTS: tuple[Joint, ...] = (
    Joint("sternoclavicular", "thorax", "clavicle", "yxz",
          ("clavicle_protraction", "clavicle_elevation", None), (1, -1, 0), "clavicle_axial"),
    Joint("shoulder", "clavicle", "upper_arm", "zxy",
          ("shoulder_flexion", "shoulder_abduction", "shoulder_rotation"), (1, -1, 1), ""),
    Joint("elbow", "upper_arm", "forearm", "zxy",
          ("elbow_flexion", None, "forearm_pronation"), (1, 0, 1), "elbow_carrying"),
    Joint("wrist", "forearm", "hand", "xzy",
          ("wrist_flexion", "wrist_deviation", None), (1, -1, 0), "wrist_twist"),
)

#: The nine joint angles, in chain order.
ANGLE_NAMES: tuple[str, ...] = tuple(a for j in JOINTS for a in j.angles if a is not None)

#: The derived, singularity-free angle between the upper arm and the thorax's long axis.
ELEVATION = "shoulder_elevation"

#: Every angle the product reports.
REPORTED_ANGLES: tuple[str, ...] = (*ANGLE_NAMES, ELEVATION)

#: AAOS normal ranges in this contract's signs [deg] (``docs/spec/kinematics.md``).
NORMAL_RANGE_DEG: dict[str, tuple[float, float]] = {
    "shoulder_flexion": (-60.0, 180.0),
    "shoulder_abduction": (0.0, 180.0),
    "shoulder_rotation": (-90.0, 70.0),
    "elbow_flexion": (0.0, 150.0),
    "forearm_pronation": (-80.0, 80.0),
    "wrist_flexion": (-70.0, 80.0),
    "wrist_deviation": (-20.0, 30.0),
    "shoulder_elevation": (0.0, 180.0),
}

#: The seed paper's Table 2 (Tsilomitrou et al. 2021) mapped to this contract's signs [deg].
#: The paper's negative rotation is internal, so its −90…20 is −20…90 here.
PAPER_RANGE_DEG: dict[str, tuple[float, float]] = {
    "shoulder_flexion": (-60.0, 180.0),
    "shoulder_abduction": (0.0, 180.0),
    "shoulder_rotation": (-20.0, 90.0),
    "elbow_flexion": (0.0, 130.0),
    "forearm_pronation": (-90.0, 90.0),
    "wrist_flexion": (-70.0, 70.0),
    "wrist_deviation": (-10.0, 25.0),
}
