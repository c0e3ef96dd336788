"""Angular velocity of an evenly sampled angle: an optional zero-phase low-pass, then the
central difference.

Angles in [rad], rates in [Hz], velocities in [rad/s]. The low-pass is a 4th-order
Butterworth run forwards and backwards (``scipy.signal.sosfiltfilt``): no delay, so
peaks and onsets keep their times. It is skipped when the cut-off is not below 0.45 of the
sample rate (nothing to remove) or the stretch is too short for the filter's padding.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from ..errors import InvalidArgument

_ORDER = 4


def lowpass(x: np.ndarray, rate_hz: float, cutoff_hz: float | None) -> np.ndarray:
    """``x`` (M,) sampled evenly at ``rate_hz`` [Hz], low-passed at ``cutoff_hz`` [Hz]
    (``None``: unchanged). Shape (M,)."""
    x = np.asarray(x, dtype=float)
    if cutoff_hz is None or cutoff_hz >= 0.45 * rate_hz:
        return x.copy()
    if not cutoff_hz > 0:
        raise InvalidArgument(f"cutoff_hz must be > 0 or None, got {cutoff_hz!r}")
    sos = butter(_ORDER, cutoff_hz, fs=rate_hz, output="sos")
    padlen = 3 * (2 * len(sos) + 1)
    if x.size <= padlen:
        return x.copy()
    return sosfiltfilt(sos, x)


def angular_velocity(angle: np.ndarray, rate_hz: float) -> np.ndarray:
    """dθ/dt [rad/s] of ``angle`` [rad] (M,) sampled evenly at ``rate_hz`` [Hz]: central
    differences inside, second-order one-sided at the ends (``np.gradient``). Shape (M,)."""
    angle = np.asarray(angle, dtype=float)
    if angle.size < 2:
        return np.zeros_like(angle)
    return np.gradient(angle, 1.0 / rate_hz, edge_order=2 if angle.size > 2 else 1)
