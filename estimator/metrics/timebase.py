"""The time base metrics run on: time windows, contiguous stretches, a uniform grid.

Times are seconds on the recording's clock, shape ``(N,)``, increasing. A window is a
half-open interval ``[start_s, end_s)``; windows come as a sequence of pairs (or an
array of shape ``(W, 2)``), e.g. the calibration poses of a recording's header (to
exclude) or a session's exercise marks (to include).

Times may repeat (packed samples share a stamp, ``docs/spec/recording.md``): a series'
times are non-decreasing, and equal stamps are collapsed (their mean value) before a
rate is estimated or a series interpolated.

Repetitions, velocities and spectra need evenly spaced samples: a stretch of samples
(no gap longer than ``max_gap_s``) is linearly interpolated onto a grid at the median
rate of its timestamps (``sampling.sample_interval_s``), which absorbs timestamp jitter
and short runs of lost samples. A grid never has more than ``GRID_FACTOR`` points per
sample it came from, whatever the stamps or a given rate say (issue 17: stamps 10 ns
apart once asked for a 30 GiB grid).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InvalidArgument, InvalidShape
from ..sampling import GRID_FACTOR, packets, sample_interval_s

__all__ = ["GRID_FACTOR", "Windows", "as_series", "as_windows", "collapse_equal",
           "in_windows", "median_rate_hz", "runs", "select", "stretches", "uniform"]

#: Time windows: pairs ``(start_s, end_s)`` [s], half-open, shape ``(W, 2)``.
Windows = Sequence[tuple[float, float]] | np.ndarray


def as_series(t: np.ndarray, x: np.ndarray, what: str = "angle") -> tuple[np.ndarray, np.ndarray]:
    """``t`` [s] and ``x`` as float arrays of the same shape ``(N,)``; ``t`` finite and
    non-decreasing (equal stamps are packed samples). Raises InvalidShape /
    InvalidArgument naming what came."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1:
        raise InvalidShape(f"t must have shape (N,), got {t.shape}")
    if x.shape != t.shape:
        raise InvalidShape(f"{what} must have the shape of t {t.shape}, got {x.shape}")
    if not np.all(np.isfinite(t)):
        raise InvalidArgument("t must be finite; a missing sample is a NaN value, not a NaN time")
    steps = np.diff(t)
    if np.any(steps < 0):
        i = int(np.flatnonzero(steps < 0)[0])
        raise InvalidArgument(f"t must not go backwards: sample {i + 1} at "
                              f"{float(t[i + 1])!r} s after {float(t[i])!r} s")
    return t, x


def collapse_equal(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Non-decreasing times ``t`` [s] (N,) and values ``x`` (N,) with equal stamps merged:
    the distinct times (G,) increasing, and the mean value of each (G,)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    u, k = packets(t)
    if u.size == t.size:
        return t, x
    starts = np.concatenate(([0], np.cumsum(k)[:-1]))
    return u, np.add.reduceat(x, starts) / k


def as_windows(windows: Windows | None, what: str = "windows") -> np.ndarray:
    """Windows as a ``(W, 2)`` float array ``[start_s, end_s)``; ``None`` → ``(0, 2)``."""
    if windows is None:
        return np.zeros((0, 2))
    w = np.asarray(windows, dtype=float)
    if w.size == 0:
        return np.zeros((0, 2))
    if w.ndim != 2 or w.shape[1] != 2:
        raise InvalidShape(f"{what} must be pairs (start_s, end_s) of shape (W, 2), "
                           f"got {w.shape}")
    bad = ~(w[:, 0] <= w[:, 1])
    if np.any(bad):
        a, b = w[np.flatnonzero(bad)[0]]
        raise InvalidArgument(f"{what}: a window must start before it ends, got ({a}, {b})")
    return w


def in_windows(t: np.ndarray, windows: Windows | None) -> np.ndarray:
    """Whether each time ``t`` [s], shape (N,), lies in any window; shape (N,) bool."""
    w = as_windows(windows)
    t = np.asarray(t, dtype=float)
    return np.any((t[:, None] >= w[:, 0]) & (t[:, None] < w[:, 1]), axis=1)


def select(t: np.ndarray, include: Windows | None = None,
           exclude: Windows | None = None) -> np.ndarray:
    """Samples to use, shape (N,) bool: inside ``include`` (all samples when ``None``) and
    outside ``exclude``."""
    t = np.asarray(t, dtype=float)
    keep = np.ones(t.shape, dtype=bool) if include is None else in_windows(t, include)
    return keep & ~in_windows(t, exclude)


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop indices (stop exclusive) of the runs of ``True`` in ``mask`` (N,)."""
    edges = np.diff(np.concatenate(([0], np.asarray(mask, dtype=np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def stretches(t: np.ndarray, selected: np.ndarray, valid: np.ndarray,
              max_gap_s: float) -> list[np.ndarray]:
    """Indices of the valid samples within each run of selected samples, cut further
    wherever consecutive valid samples are more than ``max_gap_s`` [s] apart.

    ``t``: [s], (N,); ``selected``: (N,) bool, the time windows in use (a sample left out
    by a window always cuts); ``valid``: (N,) bool, e.g. finite (an invalid sample only
    cuts when it makes a gap longer than ``max_gap_s``). Returns index arrays in time
    order.
    """
    starts, stops = runs(selected)
    out: list[np.ndarray] = []
    for a, b in zip(starts, stops, strict=True):  # loop over windows' runs
        idx = a + np.flatnonzero(valid[a:b])
        if idx.size == 0:
            continue
        cuts = np.flatnonzero(np.diff(t[idx]) > max_gap_s) + 1
        out.extend(np.split(idx, cuts))
    return out


def median_rate_hz(t: np.ndarray) -> float:
    """The median sample rate of non-decreasing times ``t`` [s] (N ≥ 2,) [Hz], equal
    stamps counted as packed samples (``sampling.sample_interval_s``)."""
    interval = sample_interval_s(t)
    if not interval > 0:
        raise InvalidArgument(f"a rate needs at least 2 distinct times, got "
                              f"{np.unique(np.asarray(t, dtype=float)).size}")
    return 1.0 / interval


def uniform(t: np.ndarray, x: np.ndarray,
            rate_hz: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """``x`` (N,) at non-decreasing times ``t`` [s] linearly interpolated onto an even grid
    from ``t[0]`` (equal stamps collapsed to their mean first).

    ``rate_hz``: the grid's rate [Hz], default the median rate of ``t``; either is capped
    so that the grid has at most ``GRID_FACTOR × (N − 1) + 1`` points. Returns the grid
    times [s] (M,), the values (M,) and the rate [Hz]. The grid ends at or before ``t[-1]``.
    """
    t = np.asarray(t, dtype=float)
    u, v = collapse_equal(t, x)
    if u.size < 2:
        raise InvalidArgument(f"an even grid needs at least 2 distinct times, got {u.size}")
    rate = median_rate_hz(t) if rate_hz is None else float(rate_hz)
    if not rate > 0:
        raise InvalidArgument(f"rate_hz must be > 0, got {rate_hz!r}")
    rate = min(rate, GRID_FACTOR * (t.size - 1) / (u[-1] - u[0]))
    m = int(np.floor((u[-1] - u[0]) * rate + 1e-9)) + 1
    grid = u[0] + np.arange(m) / rate
    return grid, np.interp(grid, u, v), rate
