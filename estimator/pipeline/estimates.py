"""What the pipeline gives: joint angles and the arm's pose at the reference sensor's times."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..arm.forward import POINTS
from ..arm.joints import REPORTED_ANGLES, SEGMENTS

#: The order a reference sensor is chosen in (``docs/spec/kinematics.md``, "Estimates").
REFERENCE_ORDER = ("upper_arm", "forearm", "hand", "trunk", "clavicle")

#: The rotations the 2-DoF joints cannot express, reported beside the angles.
RESIDUALS = ("clavicle_axial", "elbow_carrying", "wrist_twist")


@dataclass(frozen=True, slots=True)
class EstimateArrays:
    """Estimates as the compiled kernels give them, without a view per name: ``t`` [s]
    (N,); ``angles`` [rad] (N, 10) in ``REPORTED_ANGLES`` order; ``residuals`` [rad] (N, 3)
    in ``RESIDUALS`` order; ``positions`` [m] (N, 4, 3) in ``POINTS`` order, thorax frame;
    ``R_world_segment`` (N, 5, 3, 3) in ``SEGMENTS`` order. ``Estimates`` names them."""

    t: np.ndarray
    angles: np.ndarray
    residuals: np.ndarray
    positions: np.ndarray
    R_world_segment: np.ndarray

    @staticmethod
    def concatenate(parts: Sequence[EstimateArrays]) -> EstimateArrays:
        """Consecutive estimates as one (at least one part)."""
        return EstimateArrays(*(np.concatenate([getattr(p, name) for p in parts])
                                for name in ("t", "angles", "residuals", "positions",
                                             "R_world_segment")))

    def named(self) -> Estimates:
        """The same numbers as ``Estimates`` (views, no copies)."""
        return Estimates(
            t=self.t, angles=dict(zip(REPORTED_ANGLES, self.angles.T, strict=True)),
            residuals=dict(zip(RESIDUALS, self.residuals.T, strict=True)),
            positions=dict(zip(POINTS, self.positions.swapaxes(0, 1), strict=True)),
            R_world_segment=dict(zip(SEGMENTS, self.R_world_segment.swapaxes(0, 1),
                                     strict=True)))


@dataclass(frozen=True)
class Estimates:
    """Estimates at times ``t`` [s] (N,).

    ``angles``: ``REPORTED_ANGLES`` → [rad] (N,); ``residuals``: what the 2-DoF joints
    cannot express [rad] (N,); ``positions``: shoulder, elbow, wrist, hand → [m] (N, 3) in
    the thorax frame; ``R_world_segment``: thorax … hand → (N, 3, 3) in the world (ENU,
    heading from the magnetometer or, on 6-axis kits, from the N-pose).
    """

    t: np.ndarray
    angles: dict[str, np.ndarray]
    residuals: dict[str, np.ndarray]
    positions: dict[str, np.ndarray]
    R_world_segment: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def degrees(self) -> dict[str, np.ndarray]:
        return {k: np.rad2deg(v) for k, v in self.angles.items()}

    @staticmethod
    def empty() -> Estimates:
        """No estimates (one shared, read-only instance: a poll with nothing new is free)."""
        return _EMPTY

    @staticmethod
    def concatenate(parts: Sequence[Estimates]) -> Estimates:
        parts = [p for p in parts if len(p)] or [Estimates.empty()]

        def cat(getter):
            return {k: np.concatenate([getter(p)[k] for p in parts]) for k in getter(parts[0])}

        return Estimates(t=np.concatenate([p.t for p in parts]), angles=cat(lambda p: p.angles),
                         residuals=cat(lambda p: p.residuals),
                         positions=cat(lambda p: p.positions),
                         R_world_segment=cat(lambda p: p.R_world_segment))

    def table(self) -> tuple[list[str], np.ndarray]:
        """Columns and values of ``armtrack estimate``'s CSV: t, angles [deg], positions [m]."""
        columns = ["t", *REPORTED_ANGLES] + [f"{p}_{a}" for p in POINTS for a in "xyz"]
        values = np.column_stack([self.t, *(np.rad2deg(self.angles[k]) for k in REPORTED_ANGLES),
                                  *(self.positions[p] for p in POINTS)])
        return columns, values


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


_EMPTY = Estimates(
    t=_read_only(np.zeros(0)),
    angles={k: _read_only(np.zeros(0)) for k in REPORTED_ANGLES},
    residuals={k: _read_only(np.zeros(0)) for k in RESIDUALS},
    positions={p: _read_only(np.zeros((0, 3))) for p in POINTS},
    R_world_segment={s: _read_only(np.zeros((0, 3, 3))) for s in SEGMENTS})
