"""One sensor's stream as the pipeline keeps it: its filter, and its samples and
orientations so far, in buffers that grow by doubling (a chunk costs its own size, not the
history's) and can drop what no estimate needs any more."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidArgument
from ..orientation import OrientationFilter, make_filter

#: Columns kept per sample: t, acc (3), gyr (3), q (4).
_WIDTH = 11


@dataclass
class SensorTrack:
    """Samples of one sensor: ``t`` [s], ``acc`` [m/s²], ``gyr`` [rad/s] and the filter's
    ``q`` (R_world_sensor, wxyz), in arrival order (t non-decreasing)."""

    name: str
    filter_name: str
    filter: OrientationFilter = field(init=False)
    nine_axis: bool | None = field(default=None, init=False)
    _buffer: np.ndarray = field(default_factory=lambda: np.empty((1024, _WIDTH)), init=False)
    _start: int = field(default=0, init=False)  # first kept row
    _end: int = field(default=0, init=False)  # one past the last row
    first_t: float = field(default=np.inf, init=False)
    #: Rows forgotten so far: a kept row's absolute index is its position plus this.
    discarded: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self.filter = make_filter(self.filter_name)

    def append(self, t, acc, gyr, mag) -> None:
        """Run the filter over a chunk and keep it."""
        if len(t) == 0:
            return
        if self.nine_axis is None:
            self.nine_axis = mag is not None
        elif self.nine_axis != (mag is not None):
            raise InvalidArgument(f"sensor {self.name} changed between 6 and 9 axes mid-stream")
        if self._end > self._start and t[0] < self.last_t:
            raise InvalidArgument(
                f"t goes backwards for sensor {self.name} ({t[0]} after {self.last_t})")
        q = self.filter.update(t, acc, gyr, mag).q
        n = len(t)
        self._reserve(n)
        rows = self._buffer[self._end:self._end + n]
        rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:11] = t, acc, gyr, q
        self._end += n
        self.first_t = min(self.first_t, float(t[0]))

    def _reserve(self, n: int) -> None:
        kept = self._end - self._start
        if self._end + n <= len(self._buffer):
            return
        capacity = max(len(self._buffer), 2 * (kept + n))
        buffer = np.empty((capacity, _WIDTH))
        buffer[:kept] = self._buffer[self._start:self._end]
        self._buffer, self._start, self._end = buffer, 0, kept

    def discard_before(self, t: float) -> None:
        """Forget samples before the last one at or before ``t`` (kept for slerp)."""
        times = self._buffer[self._start:self._end, 0]
        keep_from = max(int(np.searchsorted(times, t, "right")) - 1, 0)
        self._start += keep_from
        self.discarded += keep_from

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, acc, gyr, q)`` of the samples kept (views, not copies)."""
        rows = self._buffer[self._start:self._end]
        return rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:11]

    @property
    def last_t(self) -> float:
        return float(self._buffer[self._end - 1, 0]) if self._end > self._start else -np.inf

    def window(self, start: float, end: float):
        """``(acc, gyr, q)`` of the samples with ``start ≤ t ≤ end``."""
        t, acc, gyr, q = self.arrays()
        a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
        return acc[a:b], gyr[a:b], q[a:b]
