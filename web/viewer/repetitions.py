"""Repetition counts for the panels: a running count over a sliding buffer of live poses,
and counts up to a time from a stored session's repetitions (``estimator.metrics``)."""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
from armtrack.estimator.metrics import BOTH_WAYS, Repetition, count_repetitions, detect_repetitions

#: Seconds of live poses kept for counting.
BUFFER_S = 60.0
#: Seconds between recounts of the buffer.
RECOUNT_S = 1.0


class RunningRepetitions:
    """Live counts per angle. Poses go into a ``BUFFER_S`` buffer; every ``RECOUNT_S`` the
    buffer is counted again and each excursion whose peak is newer than the last one
    counted is kept, so an excursion is counted once even as the buffer slides on; the
    count is the report's (``count_repetitions``: on a both-ways angle a turn to each side
    is one)."""

    def __init__(self, names: Sequence[str]):
        self.names = tuple(names)
        self._t: deque[float] = deque()
        self._values: dict[str, deque[float]] = {k: deque() for k in self.names}
        self.counts: dict[str, int] = dict.fromkeys(self.names, 0)
        self._found: dict[str, list[Repetition]] = {k: [] for k in self.names}
        self._last_peak: dict[str, float] = dict.fromkeys(self.names, -np.inf)
        self._last_count = -np.inf

    def add(self, t: float, angles_deg: Mapping[str, float]) -> None:
        """One pose at session time ``t`` [s], angles [deg]; recounts when due."""
        if self._t and t <= self._t[-1]:
            return
        self._t.append(t)
        for k in self.names:
            self._values[k].append(angles_deg.get(k, np.nan))
        while self._t and self._t[0] < t - BUFFER_S:
            self._t.popleft()
            for k in self.names:
                self._values[k].popleft()
        if t - self._last_count >= RECOUNT_S:
            self._last_count = t
            self._recount()

    def _recount(self) -> None:
        t = np.fromiter(self._t, float)
        if t.size < 10:
            return
        for k in self.names:
            values = np.radians(np.fromiter(self._values[k], float))
            if not np.isfinite(values).any() or np.nanmax(values) - np.nanmin(values) < 0.1:
                continue
            for rep in detect_repetitions(values, t):
                if rep.peak_s > self._last_peak[k] + 1e-9:
                    self._found[k].append(rep)
                    self._last_peak[k] = rep.peak_s
            self.counts[k] = count_repetitions(self._found[k], k in BOTH_WAYS)


def counted_by(repetitions: Mapping[str, Sequence[Repetition]], t: float) -> dict[str, int]:
    """Per angle, the repetitions of a stored session's excursions ended by time ``t``
    [s] (``count_repetitions``)."""
    return {k: count_repetitions([r for r in reps if r.end_s <= t], k in BOTH_WAYS)
            for k, reps in repetitions.items()}
