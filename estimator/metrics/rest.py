"""The rest level of an angle series: the angle a repetition leaves from and returns to.

Angles in [rad], times in [s]. The rest level is a function of time, ``(N,)``, so that a
slowly drifting estimate (a 6-axis heading, a slipping sensor) still returns to *its*
rest. Three sources, in order of preference:

1. **Given**: a constant level.
2. **Rest windows** (the caller knows when the arm was at rest, e.g. the N-pose of the
   calibration): the median angle in each window, placed at the window's mid-time and
   linearly interpolated between windows (held constant before the first and after the
   last).
3. **The series' mode, tracked** (no windows): the rest position is where the arm is
   still most of the time. First the *mode* of the still samples (speed below
   ``still_speed``): a histogram with ``bin_width`` bins, smoothed over three bins; its
   peak refined to the median of the still samples within ``band`` of it. Then, to follow
   drift, the level is re-estimated locally: the still samples within ``band`` of the
   current level are the rest samples; their median per block of ``drift_window_s``
   seconds, placed at their median time and interpolated linearly (continued along the
   first and last segments beyond the end knots), is the new level; repeated until it no
   longer changes. A drift of less than ``band`` per block is
   followed; faster drift is not (give rest windows then). A tremor at rest that passes
   the low-pass makes the level uncertain by up to its filtered amplitude (the still
   samples sit at its turning points).

   Why the mode and not the median: a session's samples are not centred on rest (an
   elbow exercise spends half its time flexed), but the arm is still at rest — between
   repetitions, between sets, before and after — for longer than it is still at any
   other angle. An angle held away from zero for a whole exercise (the elbow at 90°
   while the forearm pronates) has that hold as its rest, so holding is not counted as
   a repetition.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidArgument
from ..sampling import sample_interval_s
from .timebase import Windows, as_windows

_MAX_ITERATIONS = 20
#: A block needs rest samples covering this fraction of its length to place a level.
_MIN_REST_FRACTION = 0.02


def rest_from_windows(t_query: np.ndarray, t: np.ndarray, angle: np.ndarray,
                      rest_windows: Windows) -> np.ndarray:
    """Rest level [rad] at times ``t_query`` [s] (M,), from the median of ``angle`` [rad]
    (N,) at times ``t`` [s] (N,) within each rest window. NaN angles are skipped.
    Shape (M,)."""
    w = as_windows(rest_windows, "rest_windows")
    centres, levels = [], []
    for a, b in w:  # loop over windows
        inside = (t >= a) & (t < b) & np.isfinite(angle)
        if np.any(inside):
            centres.append(0.5 * (a + b))
            levels.append(float(np.median(angle[inside])))
    if not levels:
        raise InvalidArgument(f"no angle samples inside the rest windows {w.tolist()}")
    order = np.argsort(centres)
    return np.interp(t_query, np.asarray(centres)[order], np.asarray(levels)[order])


def rest_by_mode(t: np.ndarray, angle: np.ndarray, speed: np.ndarray, *, band: float,
                 still_speed: float, bin_width: float, drift_window_s: float) -> np.ndarray:
    """Rest level [rad] at each time ``t`` [s] (N,) of a smoothed ``angle`` [rad] (N,) with
    angular ``speed`` [rad/s] (N,), as described in the module docstring. Shape (N,).

    ``band`` [rad]: samples within it of the level are at rest; ``still_speed`` [rad/s];
    ``bin_width`` [rad]: the histogram's bins; ``drift_window_s`` [s]: the blocks drift is
    tracked over.
    """
    still = np.abs(speed) < still_speed
    if not np.any(still):
        still = np.ones_like(still)  # never still: fall back to all samples
    level0 = _mode(angle[still], band, bin_width)
    level = np.full(t.shape, level0)
    if t.size < 2:
        return level
    block = np.floor((t - t[0]) / drift_window_s).astype(np.int64)  # non-decreasing
    dt = sample_interval_s(t)
    if not dt > 0:
        return level
    min_count = max(3, int(_MIN_REST_FRACTION * drift_window_s / dt))
    for _ in range(_MAX_ITERATIONS):
        rest = np.flatnonzero(still & (np.abs(angle - level) < band))
        groups = np.split(rest, np.flatnonzero(np.diff(block[rest])) + 1)
        times, levels = [], []
        for members in groups:  # loop over blocks
            if members.size >= min_count:
                times.append(float(np.median(t[members])))
                levels.append(float(np.median(angle[members])))
        if not levels:
            break
        new = _interpolate(t, np.asarray(times), np.asarray(levels))
        converged = np.max(np.abs(new - level)) < 1e-3 * band
        level = new
        if converged:
            break
    return level


def _interpolate(t: np.ndarray, knots_t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear through the knots, continued along the first and last segments
    beyond them (a drift goes on at the ends); constant with a single knot."""
    level = np.interp(t, knots_t, knots)
    if knots.size > 1:
        head, tail = t < knots_t[0], t > knots_t[-1]
        level[head] = knots[0] + (t[head] - knots_t[0]) * (
            (knots[1] - knots[0]) / (knots_t[1] - knots_t[0]))
        level[tail] = knots[-1] + (t[tail] - knots_t[-1]) * (
            (knots[-1] - knots[-2]) / (knots_t[-1] - knots_t[-2]))
    return level


def _mode(values: np.ndarray, band: float, bin_width: float) -> float:
    """The most populated value of ``values`` (K,): the peak of a 3-bin-smoothed histogram,
    refined to the median of the values within ``band`` of it."""
    lo, hi = float(values.min()), float(values.max())
    nbins = max(1, int(np.ceil((hi - lo) / bin_width)) + 1)
    counts, edges = np.histogram(values, bins=nbins, range=(lo, lo + nbins * bin_width))
    smoothed = np.convolve(counts, np.ones(3), mode="same")
    peak = 0.5 * (edges[np.argmax(smoothed)] + edges[np.argmax(smoothed) + 1])
    near = np.abs(values - peak) < band
    return float(np.median(values[near])) if np.any(near) else peak
