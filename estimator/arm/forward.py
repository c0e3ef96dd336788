"""Forward kinematics of the 9-DoF arm (``docs/spec/kinematics.md``), vectorised over time.

Joint angles [rad] → every segment's orientation in the thorax frame and every joint's
position in the thorax frame [m]. Angles left out are 0 (a joint without a sensor).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..body import SegmentLengths, Side
from ..errors import InvalidArgument
from ..rotations import elemental, mirror_sagittal
from .joints import ANGLE_NAMES, JOINTS

#: Points of the arm whose positions forward kinematics gives, proximal to distal.
POINTS: tuple[str, ...] = ("shoulder", "elbow", "wrist", "hand")


@dataclass(frozen=True)
class ArmPose:
    """The arm's pose over time.

    ``R_thorax``: segment name → ``(..., 3, 3)`` rotation ``R_thorax_segment`` for
    ``clavicle``, ``upper_arm``, ``forearm``, ``hand`` (and the identity for ``thorax``).
    ``p_thorax``: point name → ``(..., 3)`` position [m] in the thorax frame, origin at the
    sternal notch, for ``shoulder``, ``elbow``, ``wrist`` and ``hand`` (the hand tip).
    """

    R_thorax: dict[str, np.ndarray]
    p_thorax: dict[str, np.ndarray]


def check_side(side: str) -> Side:
    if side not in ("right", "left"):
        raise InvalidArgument(f"side must be 'right' or 'left', got {side!r}")
    return side  # type: ignore[return-value]


def joint_rotation(joint_index: int, angles: Mapping[str, np.ndarray], shape: tuple) -> np.ndarray:
    """``R_parent_child`` of one joint of the right-arm chain, ``(*shape, 3, 3)``."""
    joint = JOINTS[joint_index]
    R = np.broadcast_to(np.eye(3), (*shape, 3, 3))
    for axis, name, sign in zip(joint.sequence, joint.angles, joint.signs, strict=True):
        if name is None or name not in angles:
            continue
        R = R @ elemental(axis, sign * np.broadcast_to(angles[name], shape))
    return R


def forward_kinematics(
    angles: Mapping[str, np.ndarray | float], side: Side, lengths: SegmentLengths
) -> ArmPose:
    """Segment orientations and joint positions in the thorax frame.

    ``angles``: joint-angle name (``ANGLE_NAMES``) → angle [rad], scalar or shape ``(...)``;
    missing angles are 0. ``side``: ``"right"`` or ``"left"``. ``lengths``: segment lengths.
    """
    check_side(side)
    unknown = set(angles) - set(ANGLE_NAMES)
    if unknown:
        raise InvalidArgument(
            f"unknown joint angle(s) {sorted(unknown)}; expected names from {list(ANGLE_NAMES)}"
        )
    arrays = {k: np.asarray(v, dtype=float) for k, v in angles.items()}
    shape = np.broadcast_shapes(*(a.shape for a in arrays.values())) if arrays else ()

    R_thorax = {"thorax": np.broadcast_to(np.eye(3), (*shape, 3, 3))}
    R = R_thorax["thorax"]
    for i, joint in enumerate(JOINTS):
        R = R @ joint_rotation(i, arrays, shape)
        R_thorax[joint.child] = R

    down = np.array([0.0, -1.0, 0.0])
    shoulder = R_thorax["clavicle"] @ np.array([0.0, 0.0, lengths.clavicle])
    elbow = shoulder + lengths.upper_arm * (R_thorax["upper_arm"] @ down)
    wrist = elbow + lengths.forearm * (R_thorax["forearm"] @ down)
    hand = wrist + lengths.hand * (R_thorax["hand"] @ down)
    p_thorax = {"shoulder": shoulder, "elbow": elbow, "wrist": wrist, "hand": hand}

    if side == "left":
        R_thorax = {k: mirror_sagittal(v) for k, v in R_thorax.items()}
        p_thorax = {k: v * np.array([1.0, 1.0, -1.0]) for k, v in p_thorax.items()}
    return ArmPose(R_thorax=R_thorax, p_thorax=p_thorax)
