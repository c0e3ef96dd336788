"""One pose of the arm as the viewer draws it, from a live update or a stored estimate row.

Positions ``p_thorax`` [m] are in the thorax frame (X anterior, Y superior, Z right,
origin at the sternal notch); orientations ``R_world`` are segment → world ENU rotations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from armtrack.estimator.arm.forward import POINTS, forward_kinematics
from armtrack.estimator.arm.joints import ANGLE_NAMES, REPORTED_ANGLES, SEGMENTS
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.rotations import quat_to_matrix

#: (min, max) so far per angle [deg].
Rom = dict[str, tuple[float, float]]


@dataclass(frozen=True)
class Pose:
    """The arm at session time ``t`` [s]."""

    t: float
    #: angle name → value [deg] (``REPORTED_ANGLES``; NaN where unknown)
    angles_deg: dict[str, float]
    #: ``shoulder``, ``elbow``, ``wrist``, ``hand`` (tip) → (3,) [m], thorax frame
    p_thorax: dict[str, np.ndarray]
    #: segment → (3, 3) rotation segment → world ENU
    R_world: dict[str, np.ndarray]
    #: running range of motion: angle → (min, max) [deg]
    rom_deg: Rom = field(default_factory=dict)

    @property
    def R_thorax(self) -> dict[str, np.ndarray]:
        """segment → (3, 3) rotation segment → thorax."""
        R_thorax_world = self.R_world["thorax"].T
        return {s: R_thorax_world @ R for s, R in self.R_world.items()}

    @property
    def side_sign(self) -> float:
        """+1 for a right arm, −1 for a left one (the shoulder's thorax Z)."""
        return -1.0 if self.p_thorax["shoulder"][2] < 0 else 1.0

    def is_finite(self) -> bool:
        return all(np.isfinite(v).all() for v in (*self.p_thorax.values(),
                                                   *self.R_world.values()))

    def is_drawable(self) -> bool:
        """Whether the trunk and shoulder are known: the arm can be drawn, its unknown
        segments (a sensor that stopped sending, ``server/live/estimator.py``) left out."""
        return bool(np.isfinite(self.R_world["thorax"]).all()
                    and np.isfinite(self.p_thorax["shoulder"]).all())

    def lengths(self) -> SegmentLengths | None:
        """Segment lengths [m] measured between this pose's points, or None."""
        p = self.p_thorax
        if not self.is_finite():
            return None
        try:
            return SegmentLengths(
                clavicle=float(np.linalg.norm(p["shoulder"])),
                upper_arm=float(np.linalg.norm(p["elbow"] - p["shoulder"])),
                forearm=float(np.linalg.norm(p["wrist"] - p["elbow"])),
                hand=float(np.linalg.norm(p["hand"] - p["wrist"])))
        except Exception:
            return None

    @classmethod
    def from_update(cls, update: Mapping[str, Any]) -> Pose:
        """From a live ``pose`` update of the hub (``server/live/worker.py``)."""
        rom = {k: (float(v["min"]), float(v["max"]))
               for k, v in (update.get("rom_deg") or {}).items()}
        return cls(
            t=float(update["t"]),
            angles_deg={k: _float(update["angles_deg"].get(k)) for k in REPORTED_ANGLES},
            p_thorax={k: np.asarray(update["positions_m"][k], dtype=float) for k in POINTS},
            R_world={s: quat_to_matrix(np.asarray(update["segments_q"][s], dtype=float))
                     for s in SEGMENTS},
            rom_deg=rom)

    @classmethod
    def zero(cls, lengths: SegmentLengths, side: str) -> Pose:
        """The zero pose (N-pose) facing world +x [thorax X = east], all angles 0."""
        arm = forward_kinematics({}, side, lengths)  # type: ignore[arg-type]
        R_world_thorax = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # Y up, Z south
        return cls(t=0.0, angles_deg=dict.fromkeys(REPORTED_ANGLES, 0.0),
                   p_thorax={k: np.asarray(arm.p_thorax[k], dtype=float) for k in POINTS},
                   R_world={s: R_world_thorax @ np.asarray(arm.R_thorax[s]) for s in SEGMENTS})


class EstimateTable:
    """A stored estimate table (``store.processing.stored_estimates``): columns ``t``,
    ``REPORTED_ANGLES`` [deg], ``<point>_x|y|z`` [m, thorax frame], ``<segment>_qw…qz``
    (segment → world)."""

    def __init__(self, columns: Sequence[str], values: np.ndarray):
        index = {c: i for i, c in enumerate(columns)}
        missing = [c for c in ("t", *REPORTED_ANGLES, *(f"{p}_{a}" for p in POINTS for a in "xyz"),
                               *(f"{s}_q{a}" for s in SEGMENTS for a in "wxyz"))
                   if c not in index]
        if missing:
            raise ValueError(f"stored estimates lack the columns {missing}")
        values = np.asarray(values, dtype=float)
        self.t = values[:, index["t"]]
        self.angles_deg = {k: values[:, index[k]] for k in REPORTED_ANGLES}
        self.points = {p: values[:, [index[f"{p}_{a}"] for a in "xyz"]] for p in POINTS}
        self.quats = {s: values[:, [index[f"{s}_q{a}"] for a in "wxyz"]] for s in SEGMENTS}

    def __len__(self) -> int:
        return len(self.t)

    def pose(self, i: int, rom_deg: Rom | None = None) -> Pose:
        return Pose(t=float(self.t[i]),
                    angles_deg={k: float(v[i]) for k, v in self.angles_deg.items()},
                    p_thorax={p: v[i].copy() for p, v in self.points.items()},
                    R_world={s: quat_to_matrix(q[i]) for s, q in self.quats.items()},
                    rom_deg=rom_deg or {})


def chain_angles_rad(angles_deg: Mapping[str, float]) -> dict[str, float]:
    """The chain's joint angles [rad] (``ANGLE_NAMES``), unknown ones as 0."""
    return {k: math.radians(v) if math.isfinite(v) else 0.0
            for k in ANGLE_NAMES if (v := angles_deg.get(k, 0.0)) is not None}


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)
