"""What every orientation filter is: the interface the pipeline and ``armtrack orient`` use.

A filter estimates ``q = R_world_sensor`` (quaternion ``wxyz``, sensor to earth) of one IMU
from its samples. The earth frame is ENU: x east, y north, z up; gravity ``(0, 0, -9.81)``.
A 6-axis filter (no magnetometer) has no absolute heading: its yaw starts at 0 (the sensor's
initial heading is the world's x) and drifts with the gyroscope's residual bias.

Inputs, per sample: ``t`` [s] (N,), non-decreasing — ``dt`` comes from each sample's
timestamp, never from a nominal rate; ``acc`` specific force [m/s²] (N, 3); ``gyr`` angular
rate [rad/s] (N, 3); ``mag`` magnetic field [µT] (N, 3) or None.

A filter is three small things: a frozen ``Params`` dataclass, a ``State`` dataclass, and
the filter with ``update(t, acc, gyr, mag)`` for one chunk (carrying the state) and
``update_batch`` for a whole recording from a fresh state. Feeding a recording in chunks of
any size gives the same quaternions as one batch, to 1e-9.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..errors import InvalidArgument, InvalidShape


@dataclass(frozen=True)
class OrientationOutput:
    """Filter output for a chunk: ``q`` (N, 4) ``R_world_sensor`` wxyz; ``gyr_bias`` (N, 3)
    the gyroscope bias estimate [rad/s] after each sample (zeros if the filter has none);
    ``rest`` (N,) bool, whether the sensor was detected at rest; ``mag_disturbed`` (N,) bool,
    whether the magnetometer was ignored as disturbed (False for 6-axis)."""

    q: np.ndarray
    gyr_bias: np.ndarray
    rest: np.ndarray
    mag_disturbed: np.ndarray


class OrientationFilter(Protocol):
    """The interface of ``euler-cf``, ``ekf`` and ``qcf``."""

    name: str

    def update(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
               mag: np.ndarray | None = None) -> OrientationOutput:
        """Advance over one chunk, carrying the state from the previous chunk."""
        ...

    def update_batch(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
                     mag: np.ndarray | None = None) -> OrientationOutput:
        """A whole recording from a fresh state (the state is left as after it)."""
        ...


class RestartableFilter:
    """``reset`` and ``update_batch`` for a filter whose whole state is ``self.state``
    (None: the next sample starts it afresh) and which advances with ``update``."""

    state: object | None = None

    def reset(self) -> None:
        """Forget the state: the next sample starts the filter again."""
        self.state = None

    def update_batch(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
                     mag: np.ndarray | None = None) -> OrientationOutput:
        """A whole recording from a fresh state (the state is left as after it)."""
        self.reset()
        return self.update(t, acc, gyr, mag)  # type: ignore[attr-defined]


def check_inputs(t, acc, gyr, mag) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Arrays as float64 with matching shapes, or InvalidShape naming what is wrong."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    acc = np.ascontiguousarray(acc, dtype=np.float64)
    gyr = np.ascontiguousarray(gyr, dtype=np.float64)
    if t.ndim != 1:
        raise InvalidShape(f"t must have shape (N,), got {t.shape}")
    n = t.shape[0]
    for name, value in (("acc", acc), ("gyr", gyr)):
        if value.shape != (n, 3):
            raise InvalidShape(f"{name} must have shape ({n}, 3) like t, got {value.shape}")
    if mag is not None:
        mag = np.ascontiguousarray(mag, dtype=np.float64)
        if mag.shape != (n, 3):
            raise InvalidShape(f"mag must have shape ({n}, 3) like t, got {mag.shape}")
    return t, acc, gyr, mag


def check_time(t: np.ndarray, prev_t: float | None) -> None:
    """Timestamps must be finite and must not go backwards, within the chunk or from the
    previous one (``prev_t``, the last time the filter saw, or None)."""
    if t.size == 0:
        return
    if not np.all(np.isfinite(t)):
        raise InvalidArgument("t must be finite")
    if prev_t is not None and t[0] < prev_t:
        raise InvalidArgument(f"t goes backwards between chunks ({t[0]} after {prev_t})")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise InvalidArgument(f"t goes backwards at sample {i} ({t[i]} after {t[i - 1]})")
