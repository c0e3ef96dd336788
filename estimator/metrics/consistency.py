"""Consistency across repetitions: the coefficient of variation (CV) of the amplitude and
of the movement time.

``CV = s / mean`` with ``s`` the sample standard deviation (``ddof=1``), a ratio (0.05 is
5%); ``None`` with fewer than two repetitions. Flexion and extension of one angle usually
differ in amplitude on purpose, so ``direction`` selects one of them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument
from .repetitions import Repetition


@dataclass(frozen=True)
class Consistency:
    """CVs over ``repetitions`` repetitions [-]."""

    repetitions: int
    amplitude_cv: float | None
    movement_time_cv: float | None


def coefficient_of_variation(values: np.ndarray) -> float | None:
    """``std(ddof=1) / mean`` of ``values`` (K,) [-]; ``None`` when K < 2 or the mean is 0."""
    values = np.asarray(values, dtype=float)
    if values.size < 2 or np.mean(values) == 0:
        return None
    return float(np.std(values, ddof=1) / np.mean(values))


def consistency(repetitions: Iterable[Repetition], direction: int | None = None) -> Consistency:
    """CV of amplitude and of movement time of ``repetitions``; only those of
    ``direction`` (+1 or −1) when given."""
    if direction not in (None, 1, -1):
        raise InvalidArgument(f"direction must be +1, -1 or None, got {direction!r}")
    chosen = [r for r in repetitions if direction is None or r.direction == direction]
    return Consistency(
        repetitions=len(chosen),
        amplitude_cv=coefficient_of_variation(np.array([r.amplitude for r in chosen])),
        movement_time_cv=coefficient_of_variation(np.array([r.movement_time_s for r in chosen])),
    )
