"""Where the figure stands in the room, and quaternions for the scene's primitives.

The room is world ENU, z up, floor at z = 0; the subject's hip centre stands above the
origin. Body proportions are fractions of body height ``h`` (Drillis & Contini, as in
Winter's *Biomechanics*): hip 0.530 h and sternal notch 0.818 h above the floor.
Quaternions are wxyz.
"""

from __future__ import annotations

import numpy as np
from armtrack.estimator.rotations import matrix_to_quat

#: Height of the hip centre above the floor [fraction of body height].
HIP_HEIGHT = 0.530
#: Sternal notch to hip centre, along the thorax's −Y [fraction of body height].
TRUNK_LENGTH = 0.818 - HIP_HEIGHT


def quat(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation → (4,) wxyz."""
    return matrix_to_quat(np.asarray(R, dtype=float))


def z_to(direction: np.ndarray) -> np.ndarray:
    """The shortest rotation taking +Z onto ``direction`` (3,), as wxyz (4,); a viser
    cylinder's axis is its local Z."""
    d = np.asarray(direction, dtype=float)
    n = np.linalg.norm(d)
    if not n > 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    d = d / n
    if d[2] < -1.0 + 1e-9:
        return np.array([0.0, 1.0, 0.0, 0.0])  # half turn about X
    q = np.array([1.0 + d[2], -d[1], d[0], 0.0])  # (1 + z·d, z × d)
    return q / np.linalg.norm(q)


def between(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A cylinder from point ``a`` to ``b`` (3,) [m]: (centre (3,), wxyz (4,), length [m])."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return (a + b) / 2, z_to(b - a), float(np.linalg.norm(b - a))


def notch_in_world(R_world_thorax: np.ndarray, height_m: float) -> np.ndarray:
    """The sternal notch [m, world] of a trunk of orientation ``R_world_thorax`` (3, 3)
    pivoting about the hip centre, which stands at ``HIP_HEIGHT · h`` above the origin."""
    hip = np.array([0.0, 0.0, HIP_HEIGHT * height_m])
    return hip + R_world_thorax @ np.array([0.0, TRUNK_LENGTH * height_m, 0.0])


def heading(R_world_thorax: np.ndarray) -> np.ndarray:
    """The facing direction: the thorax's X (anterior) on the floor, unit (3,) [world]."""
    forward = np.asarray(R_world_thorax, dtype=float)[:, 0].copy()
    forward[2] = 0.0
    n = np.linalg.norm(forward)
    if not n > 1e-6:  # lying down: face along the thorax's −Y instead
        forward = -np.asarray(R_world_thorax, dtype=float)[:, 1].copy()
        forward[2] = 0.0
        n = np.linalg.norm(forward)
    return forward / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])


def yaw_quat(forward: np.ndarray) -> np.ndarray:
    """The rotation about world z taking +x onto the floor direction ``forward`` (3,)."""
    half = 0.5 * np.arctan2(forward[1], forward[0])
    return np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
