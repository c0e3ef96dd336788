"""Sample timing of one sensor: its rate, gaps and lost samples, from timestamps alone.

Equal time stamps are allowed (``docs/spec/recording.md``: kits that pack samples stamp them
alike): a run of equal stamps is one *packet* of samples stamped with its first
sample's time, whose samples share the interval up to the next packet. So a stream
stamped in pairs every 20 ms is a 100 Hz stream with nothing lost, not a 50 Hz one (nor
a 0 Hz one with a third of it lost).

Every rate estimated from time stamps is bounded by the data's size: the typical
interval is never taken below ``1 / GRID_FACTOR`` of the mean interval (span ÷ samples),
so a stream whose stamps cluster (a sample every 0.2 s, each followed by a copy 10 ns
later) cannot make a grid of 100 MHz; work on an even grid at that rate stays within
``GRID_FACTOR`` times the samples it came from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidShape

#: An interval longer than this many nominal periods is a gap (lost samples).
GAP_FACTOR = 1.5
#: A rate estimated from time stamps is at most this many times their mean rate (samples
#: per second over their span) [-]: a quarter of the samples may be present (three in
#: four lost in short gaps) before a genuine rate would be underestimated.
GRID_FACTOR = 4


def packets(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct times ``u`` [s] (G,) of non-decreasing times ``t`` [s] (N,), and how
    many samples each holds (G,) int."""
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return t, np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(np.concatenate(([True], np.diff(t) != 0)))
    return t[starts], np.diff(np.append(starts, t.size))


def sample_interval_s(t: np.ndarray) -> float:
    """The typical time between samples [s] of non-decreasing times ``t`` [s] (N,): the
    median over packets of the interval after a packet ÷ its samples, and at least the
    mean interval ÷ ``GRID_FACTOR``. 0.0 when ``t`` has fewer than 2 distinct times."""
    t = np.asarray(t, dtype=float)
    u, k = packets(t)
    if u.size < 2:
        return 0.0
    per_sample = np.diff(u) / k[:-1]
    mean = (u[-1] - u[0]) / (t.size - k[-1])
    return max(float(np.median(per_sample)), mean / GRID_FACTOR)


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

    The period is ``1 / nominal_rate_hz`` when given, else ``sample_interval_s(t)``. The
    interval after a packet of ``k`` samples is a gap when longer than
    ``k − 1 + GAP_FACTOR`` periods; it lost ``round(interval / period) − k`` samples.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise InvalidShape(f"t must have shape (N,), got {t.shape}")
    u, k = packets(t)
    if u.size < 2:
        return SamplingSummary(int(t.size), float(t[0]) if t.size else 0.0,
                               float(t[-1]) if t.size else 0.0, 0.0, 0, 0, 0.0, 0.0)
    dt = np.diff(u)
    need = k[:-1]
    typical = sample_interval_s(t)
    period = 1.0 / nominal_rate_hz if nominal_rate_hz else typical
    gaps = dt > (need - 1 + GAP_FACTOR) * period
    lost = int(np.sum(np.maximum(np.rint(dt[gaps] / period) - need[gaps], 0)))
    return SamplingSummary(
        samples=int(t.size), start_s=float(t[0]), end_s=float(t[-1]),
        rate_hz=1.0 / typical, lost=lost, gaps=int(gaps.sum()),
        longest_gap_s=float(dt.max()),
        jitter_s=float(np.median(np.abs(dt / need - typical))),
    )
