"""One sensor's stream as the pipeline keeps it: its filter, and its samples and
orientations so far (appended chunk by chunk, joined once per poll)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidArgument
from ..orientation import OrientationFilter, make_filter
from ..rotations import quat_slerp


@dataclass
class SensorTrack:
    """Samples of one sensor: ``t`` [s], ``acc`` [m/s²], ``gyr`` [rad/s] and the filter's
    ``q`` (R_world_sensor, wxyz), in arrival order (t non-decreasing)."""

    name: str
    filter_name: str
    filter: OrientationFilter = field(init=False)
    _chunks: list[tuple[np.ndarray, ...]] = field(default_factory=list, init=False)
    _joined: tuple[np.ndarray, ...] | None = field(default=None, init=False)
    finished: bool = field(default=False, init=False)
    nine_axis: bool | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.filter = make_filter(self.filter_name)

    def append(self, t, acc, gyr, mag) -> None:
        if len(t) == 0:
            return
        if self.nine_axis is None:
            self.nine_axis = mag is not None
        elif self.nine_axis != (mag is not None):
            raise InvalidArgument(f"sensor {self.name} changed between 6 and 9 axes mid-stream")
        if self._chunks and t[0] < self._chunks[-1][0][-1]:
            raise InvalidArgument(
                f"t goes backwards for sensor {self.name} ({t[0]} after {self._chunks[-1][0][-1]})")
        out = self.filter.update(t, acc, gyr, mag)
        self._chunks.append((np.asarray(t, float), np.asarray(acc, float),
                             np.asarray(gyr, float), out.q))
        self._joined = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, acc, gyr, q)`` of everything so far."""
        if self._joined is None:
            if not self._chunks:
                self._joined = (np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)))
            else:
                self._joined = tuple(np.concatenate(parts) for parts in zip(*self._chunks,
                                                                            strict=True))
                self._chunks = [self._joined]
        return self._joined  # type: ignore[return-value]

    @property
    def last_t(self) -> float:
        return float(self._chunks[-1][0][-1]) if self._chunks else -np.inf

    @property
    def first_t(self) -> float:
        return float(self._chunks[0][0][0]) if self._chunks else np.inf

    def window(self, start: float, end: float):
        """``(acc, gyr, q)`` of the samples with ``start ≤ t ≤ end``."""
        t, acc, gyr, q = self.arrays()
        a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
        return acc[a:b], gyr[a:b], q[a:b]

    def window_times(self, start: float, end: float) -> np.ndarray:
        t = self.arrays()[0]
        return t[np.searchsorted(t, start, "left"):np.searchsorted(t, end, "right")]

    def orientation_at(self, times: np.ndarray) -> np.ndarray:
        """The filter's orientation (wxyz) at ``times``: slerp between the bracketing
        samples, held before the first and after the last."""
        t, _, _, q = self.arrays()
        j = np.clip(np.searchsorted(t, times, "right") - 1, 0, len(t) - 1)
        k = np.minimum(j + 1, len(t) - 1)
        span = t[k] - t[j]
        u = np.where(span > 0, (times - t[j]) / np.where(span > 0, span, 1.0), 0.0)
        return quat_slerp(q[j], q[k], u.clip(0.0, 1.0))
