"""Rotation primitives on stacked arrays: rotation matrices ``(..., 3, 3)`` and
quaternions ``(..., 4)`` in ``wxyz`` order.

A matrix ``R_a_b`` maps vectors in frame ``b`` to frame ``a``; ``R_a_c = R_a_b @ R_b_c``.
Angles are radians. Everything is vectorised over leading axes; there is no loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .errors import InvalidArgument, InvalidShape

if TYPE_CHECKING:  # scipy (~0.3-1 s to import) loads on the first conversion that needs it
    from scipy.spatial.transform import Rotation

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def _check_matrix(R: np.ndarray) -> np.ndarray:
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise InvalidShape(f"rotation matrices must have shape (..., 3, 3), got {R.shape}")
    return R


def elemental(axis: str, angle: np.ndarray) -> np.ndarray:
    """Rotation about a frame axis ``'x'``, ``'y'`` or ``'z'`` by ``angle`` [rad].

    ``angle`` shape ``(...)`` → matrices ``(..., 3, 3)``; positive is right-handed.
    """
    if axis not in _AXIS_INDEX:
        raise InvalidArgument(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((*angle.shape, 3, 3))
    i = _AXIS_INDEX[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    R[..., i, i] = 1.0
    R[..., j, j] = c
    R[..., k, k] = c
    R[..., k, j] = s
    R[..., j, k] = -s
    return R


def compose(*matrices: np.ndarray) -> np.ndarray:
    """Product of rotation stacks, left to right (intrinsic composition)."""
    out = matrices[0]
    for R in matrices[1:]:
        out = out @ R
    return out


def tait_bryan_angles(R: np.ndarray, sequence: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles ``(a, b, c)`` [rad] with ``R = R_i(a) @ R_j(b) @ R_k(c)`` (intrinsic).

    ``sequence`` names three different axes, e.g. ``"zxy"``. ``b`` lies in [-π/2, π/2],
    ``a`` and ``c`` in (-π, π]. At ``|b| = π/2`` only ``a ∓ c`` is determined; the result
    there puts it all in ``a`` (c = 0). ``R`` shape ``(..., 3, 3)`` → three ``(...)`` arrays.
    """
    R = _check_matrix(R)
    if len(sequence) != 3 or len(set(sequence)) != 3 or set(sequence) - set(_AXIS_INDEX):
        raise InvalidArgument(f"sequence must name three different axes, got {sequence!r}")
    i, j, k = (_AXIS_INDEX[ax] for ax in sequence)
    eps = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 for cyclic order (xyz, yzx, zxy)
    sb = eps * R[..., i, k]
    cb = np.hypot(R[..., i, i], R[..., i, j])
    b = np.arctan2(sb, cb)
    a = np.arctan2(-eps * R[..., j, k], R[..., k, k])
    c = np.arctan2(-eps * R[..., i, j], R[..., i, i])
    # At the singularity (cb == 0) a and c are undefined: put the determined combination in a.
    singular = cb < 1e-12
    if np.any(singular):
        # With c = 0, R = R_i(a) R_j(±π/2) and column j of R is R_i(a) e_j.
        a_sing = np.arctan2(eps * R[..., k, j], R[..., j, j])
        a = np.where(singular, a_sing, a)
        c = np.where(singular, 0.0, c)
    return a, b, c


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle [rad] between vectors ``(..., 3)``, accurate near 0 and π."""
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` → unit quaternions ``(..., 4)`` wxyz, w ≥ 0."""
    R = _check_matrix(R)
    shape = R.shape[:-2]
    q = to_scipy_matrix(R.reshape(-1, 3, 3)).as_quat(scalar_first=True, canonical=True)
    return q.reshape(*shape, 4)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` wxyz (normalised here) → rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1] != 4:
        raise InvalidShape(f"quaternions must have shape (..., 4) wxyz, got {q.shape}")
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty((*q.shape[:-1], 3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def to_scipy_matrix(R: np.ndarray) -> Rotation:
    """The one place a matrix stack becomes a scipy ``Rotation``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, dtype=float).reshape(-1, 3, 3))


def mirror_sagittal(R: np.ndarray) -> np.ndarray:
    """``M R M`` with ``M = diag(1, 1, -1)``: a right-arm rotation as its left-arm mirror image
    (and back). Mirroring through the sagittal plane flips the signs of rotations about X and Y
    and keeps those about Z (``docs/spec/kinematics.md``, left arm)."""
    R = np.array(R, dtype=float, copy=True)
    R[..., 2, :2] *= -1.0
    R[..., :2, 2] *= -1.0
    return R


def quat_slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical interpolation from ``q0`` to ``q1`` (wxyz, ``(..., 4)``) at fractions ``u``
    (``(...)``, 0 → q0, 1 → q1), along the shorter arc."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    u = np.asarray(u, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    dot = np.abs(dot).clip(max=1.0)
    theta = np.arccos(dot)
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-9
    safe = np.where(near, 1.0, sin_theta)
    w0 = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(near, u, np.sin(u * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def yaw_of(R: np.ndarray) -> np.ndarray:
    """The rotation about world z [rad] closest to ``R`` (``(..., 3, 3)``)."""
    R = _check_matrix(R)
    return np.arctan2(R[..., 1, 0] - R[..., 0, 1], R[..., 0, 0] + R[..., 1, 1])
