"""Sample timing of one sensor: its rate, gaps and lost samples, from timestamps alone."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidShape

#: An interval longer than this many nominal periods is a gap (lost samples).
GAP_FACTOR = 1.5


@dataclass(frozen=True)
class SamplingSummary:
    """``rate_hz``: median sample rate [Hz]; ``lost``: samples missing in gaps (each gap of
    ``dt`` counts ``round(dt / period) - 1``); ``gaps``: number of gaps; ``longest_gap_s``:
    the longest interval [s]; ``jitter_s``: median absolute deviation of the intervals [s]."""

    samples: int
    start_s: float
    end_s: float
    rate_hz: float
    lost: int
    gaps: int
    longest_gap_s: float
    jitter_s: float

    @property
    def lost_fraction(self) -> float:
        return self.lost / (self.samples + self.lost) if self.samples + self.lost else 0.0


def summarise_sampling(t: np.ndarray, nominal_rate_hz: float | None = None) -> SamplingSummary:
    """Timing summary of sample times ``t`` [s], shape (N,), non-decreasing.

    The period is ``1 / nominal_rate_hz`` when given, else the median interval.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise InvalidShape(f"t must have shape (N,), got {t.shape}")
    if t.size < 2:
        return SamplingSummary(int(t.size), float(t[0]) if t.size else 0.0,
                               float(t[-1]) if t.size else 0.0, 0.0, 0, 0, 0.0, 0.0)
    dt = np.diff(t)
    median = float(np.median(dt))
    period = 1.0 / nominal_rate_hz if nominal_rate_hz else median
    if period <= 0:
        return SamplingSummary(int(t.size), float(t[0]), float(t[-1]), 0.0, 0, 0,
                               float(dt.max()), 0.0)
    gaps = dt > GAP_FACTOR * period
    lost = int(np.sum(np.maximum(np.rint(dt[gaps] / period) - 1, 0)))
    return SamplingSummary(
        samples=int(t.size), start_s=float(t[0]), end_s=float(t[-1]),
        rate_hz=1.0 / median if median > 0 else 0.0, lost=lost, gaps=int(gaps.sum()),
        longest_gap_s=float(dt.max()), jitter_s=float(np.median(np.abs(dt - median))),
    )
