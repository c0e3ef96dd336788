"""How sure the thorax's upright is, told again by the trunk's sway over the whole session.

The calibration takes the thorax's upright as the centre of the trunk's sway over the
poses (``calibrate._sway_centre``) and tells that centre's σ under a model of the sway's
spectrum (``SWAY_ERROR_SLOPE``): a few seconds cannot tell a few sines at 0.1–0.2 Hz from
a red sway, so the σ says the larger, 2.5–3 times the error on a sine-like sway
(bench/README.md). The session that follows shows how this trunk sways: the same centre,
taken over spans as long as the poses' and shifted along the session, scatters about the
trunk's long-run centre by what the poses' centre may be off, while the model tells each
of those spans a σ of its own. The σ the session ends with is the calibration's scaled by
that scatter over what was told of the same spans (per axis), never above the
calibration's: the session can show that this trunk's sway averages out better than the
pink spectrum the poses' σ assumes (a sine-like sway), but a trunk that moves more in the
exercise than in the poses (the shared ``trunk_reach``: its spans 1.9 times the poses'
variance, scaled 4.4 times) is no evidence about the poses' sway. The ``trunk-swayed``
warning is decided again from it. Only the σ and the warning change: the upright, and so
every angle, stays the calibration's (no assumption that the trunk's mean posture over
the session is upright). A session too short after the poses keeps the calibration's σ.
What it assumes: the trunk sways through the session as through the poses; one that
swayed slowly through the poses and then kept still, or moved evenly, could be told too
sure (not simulated).

The trunk's up direction is kept in ``SWAY_BLOCK_S`` blocks of absolute time as samples
arrive (a few floats a second), so a session fed whole or in chunks tells the same.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..calibration.quality import trunk_sway_warning
from .calibrate import SWAY_BLOCK_S, Calibration, _sway_centre

#: The spans are shifted along the session in steps of this [s] …
SHIFT_STEP_S = 2 * SWAY_BLOCK_S
#: … at most this many of them (spread over a long session) …
SHIFTS_MAX = 200
#: … and only when the session after the poses holds at least this many spans.
SPANS_MIN = 2.0


class SwayBlocks:
    """The trunk sensor's up direction (its unit specific force, sensor frame) summed in
    blocks of ``SWAY_BLOCK_S`` of absolute time, as samples arrive in time order. Small
    chunks (a live kit's messages) wait in a short buffer and are summed ``PENDING_ROWS``
    at a time: a few list appends a message, not a dozen numpy calls."""

    #: Rows kept before they are summed into blocks.
    PENDING_ROWS = 256

    def __init__(self) -> None:
        self._index: list[np.ndarray] = []
        self._t: list[np.ndarray] = []
        self._up: list[np.ndarray] = []
        self._count: list[np.ndarray] = []
        self._pending: list[np.ndarray] = []
        self._pending_rows = 0

    def add(self, rows: np.ndarray) -> None:
        """Samples as rows ``[t, ax, ay, az]`` (n, 4) [s, m/s²] (copied), in time order
        (the caller's track has checked them)."""
        self._pending.append(np.array(rows[:, :4], dtype=np.float64))
        self._pending_rows += len(rows)
        if self._pending_rows >= self.PENDING_ROWS:
            self._sum_pending()

    def _sum_pending(self) -> None:
        if not self._pending:
            return
        rows = np.concatenate(self._pending)
        self._pending, self._pending_rows = [], 0
        t, acc = rows[:, 0], rows[:, 1:4]
        norm = np.linalg.norm(acc, axis=1)
        usable = np.isfinite(t) & np.isfinite(norm) & (norm > 0.0)
        if not usable.any():
            return
        t, up = t[usable], acc[usable] / norm[usable, None]
        index = np.floor(t / SWAY_BLOCK_S).astype(np.int64)
        starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
        self._index.append(index[starts])
        self._t.append(np.add.reduceat(t, starts))
        self._up.append(np.add.reduceat(up, starts, axis=0))
        self._count.append(np.diff(np.r_[starts, len(t)]))

    def blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """The blocks' mean times [s] (M,) and mean up directions (M, 3), unit, in time
        order (a block split between two sums counted once)."""
        self._sum_pending()
        if not self._index:
            return np.empty(0), np.empty((0, 3))
        index, where = np.unique(np.concatenate(self._index), return_inverse=True)
        count = np.bincount(where, np.concatenate(self._count), len(index))
        t = np.bincount(where, np.concatenate(self._t), len(index)) / count
        sums = np.concatenate(self._up)
        up = np.stack([np.bincount(where, sums[:, k], len(index)) for k in range(3)], axis=1)
        return t, up / np.linalg.norm(up, axis=1, keepdims=True)


def retold_lean(calibration: Calibration, t: np.ndarray, up: np.ndarray) -> Calibration:
    """``calibration`` with its lean's σ (``lean_sd_deg``) and ``trunk-swayed`` warning told
    again by the trunk's sway over the session, ``t`` [s] and ``up`` (unit, trunk sensor
    frame) its ``SwayBlocks``; unchanged without a sway-corrected upright
    (``lean_basis``) or with under ``SPANS_MIN`` spans of the session after the poses."""
    basis = calibration.lean_basis
    if basis is None or not len(t):
        return calibration
    span = basis.end - basis.start
    room = float(t[-1]) - basis.end - span  # the shifted spans start in end…end + room
    if span <= 0.0 or room < (SPANS_MIN - 1.0) * span:
        return calibration
    shifts = basis.end + np.linspace(0.0, room, min(SHIFTS_MAX, int(room / SHIFT_STEP_S) + 1))
    after = t >= basis.end
    centre = up[after].mean(axis=0)
    centre /= np.linalg.norm(centre)
    axes = np.stack([basis.lateral, basis.forward])
    off, told = [], []
    for start in shifts:
        inside = (t >= start) & (t <= start + span)
        if np.count_nonzero(inside) < 2:
            continue
        found, covariance = _sway_centre(t[inside], up[inside])
        off.append(axes @ (found - centre))
        told.append(np.einsum("ij,jk,ik->i", axes, covariance, axes))
    if not off:
        return calibration
    scale = np.minimum(np.mean(np.square(off), axis=0)
                       / np.maximum(np.mean(told, axis=0), 1e-300), 1.0)
    lean_sd_deg = basis.lean_sd_deg(float(scale[0]), float(scale[1]))
    kept = [w for w in calibration.warnings if w.code != "trunk-swayed"]
    warning = trunk_sway_warning(*lean_sd_deg, basis.nine_axis)
    return replace(calibration, lean_sd_deg=lean_sd_deg,
                   warnings=(*kept, *(() if warning is None else (warning,))))
