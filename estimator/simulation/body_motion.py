"""Exact motion of every segment and point of the arm in the world, from joint profiles.

Each rotation of the chain (world → thorax → clavicle → upper arm → forearm → hand) is a
product of elemental rotations ``E(q)`` about fixed local axes. Composing
``R_k = R_{k-1} J`` with ``J = E_axis(q)`` gives, in body coordinates,

    ω_k = Jᵀ ω_{k-1} + q̇ e_axis
    α_k = Jᵀ α_{k-1} − (q̇ e_axis) × (Jᵀ ω_{k-1}) + q̈ e_axis

and a point ``p = p_parent + R v`` (``v`` fixed in the frame) moves with

    p̈ = p̈_parent + R (α × v + ω × (ω × v)).

So angular rates and accelerations are exact, from the profiles' closed-form derivatives,
with no numerical differentiation. World frame: ENU (x east, y north, z up). The subject
stands with the pelvis (the trunk's pivot) fixed; the sternal notch is ``trunk_length_m``
above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arm.forward import check_side
from ..arm.joints import JOINTS
from ..body import SegmentLengths, Side
from ..rotations import elemental
from .profiles import Motion, Profile

_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]),
         "z": np.array([0.0, 0.0, 1.0])}

#: Thorax axes in the world when the subject faces world +x: X anterior → +x,
#: Y superior → +z, Z right → −y.
R_WORLD_THORAX_UPRIGHT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

#: Trunk angles and the thorax axis each turns about (after the heading about world z).
TRUNK_ANGLES = (("trunk_flexion", "z"), ("trunk_lateral", "x"), ("trunk_rotation", "y"))


@dataclass(frozen=True)
class FrameMotion:
    """A frame over time: ``R`` (N, 3, 3) ``R_world_frame``; ``omega`` and ``alpha`` (N, 3)
    its angular velocity [rad/s] and acceleration [rad/s²] in its own axes."""

    R: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray

    def turn(self, axis: str, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> FrameMotion:
        """This frame followed by an elemental rotation about its own ``axis`` by ``q``."""
        J = elemental(axis, q)
        JT = np.swapaxes(J, -1, -2)
        e = _AXES[axis]
        w_parent = np.einsum("nij,nj->ni", JT, self.omega)
        a_parent = np.einsum("nij,nj->ni", JT, self.alpha)
        w_joint = dq[:, None] * e
        return FrameMotion(R=self.R @ J, omega=w_parent + w_joint,
                           alpha=a_parent - np.cross(w_joint, w_parent) + ddq[:, None] * e)

    def fixed(self, R_const: np.ndarray) -> FrameMotion:
        """This frame followed by a constant rotation ``R_const``."""
        return FrameMotion(R=self.R @ R_const, omega=self.omega @ R_const,
                           alpha=self.alpha @ R_const)


@dataclass(frozen=True)
class PointMotion:
    """A point over time: position [m], velocity [m/s], acceleration [m/s²], world, (N, 3)."""

    p: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def offset(self, frame: FrameMotion, r: np.ndarray) -> PointMotion:
        """The point at ``r`` [m] (fixed in ``frame``) from this one."""
        r = np.broadcast_to(np.asarray(r, dtype=float), self.p.shape)
        w_r = np.cross(frame.omega, r)
        local_a = np.cross(frame.alpha, r) + np.cross(frame.omega, w_r)
        return PointMotion(p=self.p + np.einsum("nij,nj->ni", frame.R, r),
                           v=self.v + np.einsum("nij,nj->ni", frame.R, w_r),
                           a=self.a + np.einsum("nij,nj->ni", frame.R, local_a))


@dataclass(frozen=True)
class BodyMotion:
    """Every segment frame (``thorax``, ``clavicle``, ``upper_arm``, ``forearm``, ``hand``)
    and every point (``sternal_notch``, ``shoulder``, ``elbow``, ``wrist``, ``hand``) over
    time, in the world."""

    t: np.ndarray
    frames: dict[str, FrameMotion]
    points: dict[str, PointMotion]


@dataclass(frozen=True)
class Stance:
    """Where the subject stands: pelvis position [m] in the world, facing ``heading`` [rad]
    about world z (0 = facing +x), sternal notch ``trunk_length_m`` above the pelvis."""

    pelvis_m: tuple[float, float, float] = (0.0, 0.0, 1.0)
    heading: float = 0.0
    trunk_length_m: float = 0.45


def body_motion(motion: Motion, side: Side, lengths: SegmentLengths, t: np.ndarray,
                stance: Stance = Stance()) -> BodyMotion:
    """Evaluate ``motion`` at times ``t`` [s] (N,): frames and points with exact rates."""
    check_side(side)
    t = np.asarray(t, dtype=float)
    n = t.size
    zero = np.zeros((n, 3))

    def profile(table: dict[str, Profile], name: str):
        return table.get(name, Profile()).evaluate(t)

    world = FrameMotion(R=np.broadcast_to(np.eye(3), (n, 3, 3)), omega=zero, alpha=zero)
    thorax = world.turn("z", *_add_offset(profile(motion.trunk, "trunk_heading"), stance.heading))
    thorax = thorax.fixed(R_WORLD_THORAX_UPRIGHT)
    for name, axis in TRUNK_ANGLES:
        thorax = thorax.turn(axis, *profile(motion.trunk, name))
    pelvis = PointMotion(p=np.broadcast_to(np.asarray(stance.pelvis_m, float), (n, 3)),
                         v=zero, a=zero)
    notch = pelvis.offset(thorax, np.array([0.0, stance.trunk_length_m, 0.0]))

    mirror = -1.0 if side == "left" else 1.0  # left arm: X and Y rotations change sign
    frames = {"thorax": thorax}
    frame = thorax
    for joint in JOINTS:
        for axis, name, sign in zip(joint.sequence, joint.angles, joint.signs, strict=True):
            if name is None:
                continue
            q, dq, ddq = profile(motion.joints, name)
            s = sign * (mirror if axis in "xy" else 1.0)
            frame = frame.turn(axis, s * q, s * dq, s * ddq)
        frames[joint.child] = frame

    down = np.array([0.0, -1.0, 0.0])
    shoulder = notch.offset(frames["clavicle"], np.array([0.0, 0.0, mirror * lengths.clavicle]))
    elbow = shoulder.offset(frames["upper_arm"], lengths.upper_arm * down)
    wrist = elbow.offset(frames["forearm"], lengths.forearm * down)
    hand = wrist.offset(frames["hand"], lengths.hand * down)
    points = {"sternal_notch": notch, "shoulder": shoulder, "elbow": elbow, "wrist": wrist,
              "hand": hand}
    return BodyMotion(t=t, frames=frames, points=points)


def _add_offset(values, offset: float):
    q, dq, ddq = values
    return q + offset, dq, ddq
