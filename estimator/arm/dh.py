"""The seeds' Denavit–Hartenberg tables as data, and the constant maps onto the spec's chain.

A DH row gives ``A = Rz(θ) · Tz(d) · Tx(a) · Rx(α)`` (standard convention, seed paper
eq. 1, thesis eq. 3.2). A joint row's ``θ = theta_offset + sign · q`` with ``q`` the
spec's joint angle [rad] named by ``joint``; a row with ``joint=None`` is constant.

**Paper** (Tsilomitrou et al. 2021, Table 3; shoulder 3, elbow 2, wrist 2, hand tip):
the table as printed plus the map

* base: ``R_thorax_dh0 = Rz(+90°)`` (so the constant link 0, ``θ = -90°``, ``d = l_c``,
  lands on the thorax axes with the shoulder at ``(0, 0, l_c)``);
* joint variables: ``θ1 = 90° + flexion``, ``θ2 = 90° - abduction``,
  ``θ3 = 90° + rotation``, ``θ4 = 180° + elbow_flexion``,
  ``θ5 = 90° + pronation`` (the one offset added to the table: the paper's forearm
  neutral is turned 90° from the spec's thumb-forward N-pose), ``θ6 = -90° + wrist_flexion``,
  ``θ7 = deviation``;
* segments: upper arm = frame 4 (after θ3), forearm = frame 6, hand = frame 8, each up to a
  constant rotation (``segment_rotation``); shoulder, elbow, wrist and hand tip are the
  origins of frames 1, 4, 6 and 8. Orientations and positions both match the spec.

**Thesis** (Lovato 2024, Table 3.1; clavicle 2, shoulder 3, elbow 2): the table as printed,
base ``R_thorax_dh0 = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]`` (its z axis, the protraction
axis, along the thorax's -Y); every joint variable with sign −1 (``θ = offset − q``), and
two offsets of +90° added to the table's, on θ2 (clavicle elevation) and θ5 (shoulder
rotation); segments: clavicle = frame 2, upper arm = frame 5, forearm = frame 7.
Orientations match the spec; positions do not (the thesis puts ``l_c`` along ``x₂``,
perpendicular to the flexion axis, while in the spec the flexion axis runs along the
clavicle), so positions follow ``forward.py``.

Both maps were found by searching the 24 axis-aligned base rotations, signs ±1 and added
offsets in 90° steps for the fewest added offsets; the tests check them on thousands of
random joint angles.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..body import SegmentLengths
from ..errors import InvalidArgument

_DEG = np.pi / 180.0


@dataclass(frozen=True)
class DHRow:
    """One DH row: link length ``a`` [m], twist ``alpha`` [rad], offset ``d`` [m],
    ``theta = theta_offset + sign * q[joint]`` [rad] (constant when ``joint`` is None)."""

    a: float
    alpha: float
    d: float
    theta_offset: float
    joint: str | None = None
    sign: int = 1


@dataclass(frozen=True)
class DHMap:
    """A DH table and the constant map that puts it on the spec's chain (right arm).

    ``R_thorax_base``: rotation of the DH base frame in the thorax frame.
    ``segment_frames``: segment → index of the DH frame it is attached to (0 = base).
    ``point_frames``: point → index of the DH frame whose origin it is (when positions match).
    """

    name: str
    rows: tuple[DHRow, ...]
    R_thorax_base: np.ndarray
    segment_frames: Mapping[str, int]
    point_frames: Mapping[str, int]


def dh_transform(row: DHRow, theta: np.ndarray) -> np.ndarray:
    """``A_{i-1}^i`` for ``theta`` [rad] of shape ``(...)`` → ``(..., 4, 4)``."""
    theta = np.asarray(theta, dtype=float)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(row.alpha), np.sin(row.alpha)
    A = np.zeros((*theta.shape, 4, 4))
    A[..., 0, 0], A[..., 0, 1], A[..., 0, 2], A[..., 0, 3] = ct, -st * ca, st * sa, row.a * ct
    A[..., 1, 0], A[..., 1, 1], A[..., 1, 2], A[..., 1, 3] = st, ct * ca, -ct * sa, row.a * st
    A[..., 2, 1], A[..., 2, 2], A[..., 2, 3] = sa, ca, row.d
    A[..., 3, 3] = 1.0
    return A


def dh_chain(rows: tuple[DHRow, ...], angles: Mapping[str, np.ndarray | float]) -> np.ndarray:
    """Frames of the chain in its base frame: ``(..., n + 1, 4, 4)``, frame 0 the identity.

    ``angles``: joint name → spec angle [rad], scalar or ``(...)``; missing joints are 0.
    """
    arrays = {k: np.asarray(v, dtype=float) for k, v in angles.items()}
    shape = np.broadcast_shapes(*(v.shape for v in arrays.values())) if arrays else ()
    frames = np.empty((*shape, len(rows) + 1, 4, 4))
    T = np.broadcast_to(np.eye(4), (*shape, 4, 4))
    frames[..., 0, :, :] = T
    for i, row in enumerate(rows):
        q = arrays.get(row.joint, 0.0) if row.joint is not None else 0.0
        T = T @ dh_transform(row, np.broadcast_to(row.theta_offset + row.sign * q, shape))
        frames[..., i + 1, :, :] = T
    return frames


def segment_rotation(dh_map: DHMap, segment: str) -> np.ndarray:
    """Constant ``R_frame_segment`` of a segment in its DH frame, from the zero pose
    (where every segment's axes are the thorax's)."""
    if segment not in dh_map.segment_frames:
        raise InvalidArgument(f"{dh_map.name} has no segment {segment!r}")
    frame = dh_chain(dh_map.rows, {})[dh_map.segment_frames[segment]]
    return (dh_map.R_thorax_base @ frame[:3, :3]).T


def dh_segment_orientations(
    dh_map: DHMap, angles: Mapping[str, np.ndarray | float]
) -> dict[str, np.ndarray]:
    """``R_thorax_segment`` (right arm) for each segment of the map, via the DH chain."""
    frames = dh_chain(dh_map.rows, angles)
    return {
        segment: dh_map.R_thorax_base @ frames[..., k, :3, :3] @ segment_rotation(dh_map, segment)
        for segment, k in dh_map.segment_frames.items()
    }


def dh_point_positions(
    dh_map: DHMap, angles: Mapping[str, np.ndarray | float]
) -> dict[str, np.ndarray]:
    """Positions [m] in the thorax frame (right arm) of the map's points, via the DH chain."""
    frames = dh_chain(dh_map.rows, angles)
    return {
        point: frames[..., k, :3, 3] @ dh_map.R_thorax_base.T
        for point, k in dh_map.point_frames.items()
    }


def paper_map(lengths: SegmentLengths) -> DHMap:
    """The seed paper's Table 3 with the map described in the module docstring."""
    lc, lu, lf, lh = lengths.clavicle, lengths.upper_arm, lengths.forearm, lengths.hand
    rows = (
        DHRow(0.0, 0.0, lc, -90 * _DEG),  # {C}, link 0: chest to shoulder
        DHRow(0.0, 90 * _DEG, 0.0, 90 * _DEG, "shoulder_flexion", +1),  # {S1}
        DHRow(0.0, 90 * _DEG, 0.0, 90 * _DEG, "shoulder_abduction", -1),  # {S2}
        DHRow(0.0, 90 * _DEG, -lu, 90 * _DEG, "shoulder_rotation", +1),  # {S3}
        DHRow(0.0, 90 * _DEG, 0.0, 180 * _DEG, "elbow_flexion", +1),  # {E1}
        DHRow(0.0, -90 * _DEG, -lf, (0 + 90) * _DEG, "forearm_pronation", +1),  # {E2}, +90° added
        DHRow(0.0, 90 * _DEG, 0.0, -90 * _DEG, "wrist_flexion", +1),  # {W1}
        DHRow(-lh, 90 * _DEG, 0.0, 0.0, "wrist_deviation", +1),  # {W2}
    )
    return DHMap(
        name="paper",
        rows=rows,
        R_thorax_base=np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
        segment_frames={"upper_arm": 4, "forearm": 6, "hand": 8},
        point_frames={"shoulder": 1, "elbow": 4, "wrist": 6, "hand": 8},
    )


def thesis_map(lengths: SegmentLengths) -> DHMap:
    """The thesis's Table 3.1 with the map described in the module docstring."""
    lc, lu, lf = lengths.clavicle, lengths.upper_arm, lengths.forearm
    rows = (
        DHRow(0.0, 90 * _DEG, 0.0, 0.0, "clavicle_protraction", -1),
        DHRow(lc, -90 * _DEG, 0.0, (0 + 90) * _DEG, "clavicle_elevation", -1),  # +90° added
        DHRow(0.0, 90 * _DEG, 0.0, 0.0, "shoulder_flexion", -1),
        DHRow(0.0, 90 * _DEG, 0.0, 90 * _DEG, "shoulder_abduction", -1),
        DHRow(0.0, 90 * _DEG, lu, (0 + 90) * _DEG, "shoulder_rotation", -1),  # +90° added
        DHRow(0.0, -90 * _DEG, 0.0, 0.0, "elbow_flexion", -1),
        DHRow(0.0, 0.0, lf, 90 * _DEG, "forearm_pronation", -1),
    )
    return DHMap(
        name="thesis",
        rows=rows,
        R_thorax_base=np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
        segment_frames={"clavicle": 2, "upper_arm": 5, "forearm": 7},
        point_frames={},
    )
