"""Movement smoothness: SPARC and the log dimensionless jerk (LDLJ), as defined by
Balasubramanian, Melendez-Calderon, Roby-Brami and Burdet, "On the analysis of movement
smoothness", J NeuroEng Rehabil 12:112 (2015), and their reference implementation
(``sparc(movement, fs, padlevel=4, fc=10.0, amp_th=0.05)``, ``log_dimensionless_jerk``).

Both take the **speed profile** of one movement, evenly sampled at ``fs`` [Hz], shape (N,),
in any unit (both are dimensionless and do not change when the speed is scaled), and
return a negative number: closer to zero is smoother.

**SPARC** (spectral arc length). The speed is zero-padded to
``nfft = 2^(ceil(log2 N) + padlevel)`` samples; ``M(f) = |FFT|`` normalised by its peak,
on ``f_k = k fs / nfft``. Of the frequencies ``f ≤ fc``, the band from the first to the
last one where ``M ≥ amp_th`` is kept (the adaptive cut-off ``f_c``), and::

    SPARC = −Σ sqrt( (Δf / (f_c − f_0))² + (ΔM)² )

over that band (``f_0`` is its first frequency, 0 for a speed profile). Only frequencies up
to the Nyquist frequency are used; with the reference's defaults (``fc`` = 10 Hz, ``fs`` ≥
20 Hz) that is the reference's result.

**LDLJ**. With ``dt = 1/fs``, duration ``T = N dt``, peak speed ``v_peak = max |v|`` and the
jerk of the speed profile ``j = Δ²v / dt²`` (``np.diff(v, 2) / dt²``)::

    LDLJ = −ln( T³ / v_peak² · Σ j² dt )

For ``v = exp(−5 t²)``, ``t = −1 … 0.99`` in steps of 0.01 s at 100 Hz: SPARC −1.41403,
LDLJ −5.81636 (the reference implementation's figures).

The angle variant takes an angle series and one time span (a repetition): the angular
speed ``|dθ/dt|`` on an even grid at the series' median rate, then SPARC and LDLJ.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import InvalidArgument, InvalidShape
from .repetitions import Repetition
from .timebase import as_series, uniform
from .velocity import angular_velocity, lowpass

#: Which part of a repetition: all of it, out to the peak, or back from it.
Phase = Literal["whole", "outward", "return"]


@dataclass(frozen=True)
class SmoothnessParams:
    """Parameters of SPARC and of the angular speed profile."""

    #: Zero padding: ``nfft = 2^(ceil(log2 N) + padlevel)`` [-].
    padlevel: int = 4
    #: Largest frequency considered for the adaptive cut-off [Hz].
    fc: float = 10.0
    #: Normalised magnitude threshold of the adaptive cut-off [-].
    amp_th: float = 0.05
    #: Low-pass of the angle before differentiating [Hz]; ``None``: none (the reference
    #: expects an already filtered speed profile).
    lowpass_hz: float | None = None

    def __post_init__(self) -> None:
        if self.padlevel < 0:
            raise InvalidArgument(f"padlevel must be ≥ 0, got {self.padlevel!r}")
        if not self.fc > 0:
            raise InvalidArgument(f"fc must be > 0 Hz, got {self.fc!r}")
        if not 0.0 < self.amp_th < 1.0:
            raise InvalidArgument(f"amp_th must be in (0, 1), got {self.amp_th!r}")


@dataclass(frozen=True)
class Smoothness:
    """SPARC and LDLJ of one movement [-]."""

    sparc: float
    ldlj: float


def sparc(speed: np.ndarray, fs: float, padlevel: int = 4, fc: float = 10.0,
          amp_th: float = 0.05) -> float:
    """Spectral arc length of a speed profile ``speed`` (N,) sampled at ``fs`` [Hz] [-]."""
    v = _profile(speed, fs, 2)
    nfft = 2 ** int(np.ceil(np.log2(v.size)) + padlevel)
    magnitude = np.abs(np.fft.rfft(v, nfft))
    magnitude = magnitude / magnitude.max()
    f = np.arange(magnitude.size) * (fs / nfft)
    within = f <= fc
    f, magnitude = f[within], magnitude[within]
    above = np.flatnonzero(magnitude >= amp_th)
    band = slice(above[0], above[-1] + 1)
    f, magnitude = f[band], magnitude[band]
    if f.size < 2:
        return 0.0
    return float(-np.sum(np.hypot(np.diff(f) / (f[-1] - f[0]), np.diff(magnitude))))


def ldlj(speed: np.ndarray, fs: float) -> float:
    """Log dimensionless jerk of a speed profile ``speed`` (N ≥ 3,) sampled at ``fs`` [Hz]
    [-]."""
    v = _profile(speed, fs, 3)
    dt = 1.0 / fs
    duration = v.size * dt
    jerk = np.diff(v, 2) / dt ** 2
    return float(-np.log(duration ** 3 / np.max(np.abs(v)) ** 2 * np.sum(jerk ** 2) * dt))


def angular_speed_profile(angle: np.ndarray, t: np.ndarray, start_s: float, end_s: float,
                          lowpass_hz: float | None = None) -> tuple[np.ndarray, float]:
    """``|dθ/dt|`` [rad/s] of ``angle`` [rad] (N,) at times ``t`` [s] (N,) between
    ``start_s`` and ``end_s`` [s] inclusive, on an even grid at the median rate of the
    finite samples there, optionally low-passed at ``lowpass_hz`` [Hz] first.
    Returns the speed (M,) and the grid's rate [Hz]."""
    t, angle = as_series(t, angle)
    inside = (t >= start_s - 1e-9) & (t <= end_s + 1e-9) & np.isfinite(angle)
    distinct = np.unique(t[inside]).size
    if distinct < 3:
        raise InvalidArgument(f"need finite samples at 3 distinct times at least in "
                              f"[{start_s}, {end_s}] s, got {distinct}")
    _, values, rate = uniform(t[inside], angle[inside])
    return np.abs(angular_velocity(lowpass(values, rate, lowpass_hz), rate)), rate


def angle_smoothness(angle: np.ndarray, t: np.ndarray, start_s: float, end_s: float,
                     params: SmoothnessParams | None = None) -> Smoothness:
    """SPARC and LDLJ of the angular speed of ``angle`` [rad] (N,), times ``t`` [s] (N,),
    between ``start_s`` and ``end_s`` [s]."""
    p = params or SmoothnessParams()
    speed, rate = angular_speed_profile(angle, t, start_s, end_s, p.lowpass_hz)
    return Smoothness(sparc=sparc(speed, rate, p.padlevel, p.fc, p.amp_th),
                      ldlj=ldlj(speed, rate))


def repetition_smoothness(angle: np.ndarray, t: np.ndarray,
                          repetitions: Iterable[Repetition],
                          params: SmoothnessParams | None = None,
                          phase: Phase = "whole") -> tuple[Smoothness, ...]:
    """``angle_smoothness`` of each repetition: ``phase`` ``"whole"`` from its start to its
    end, ``"outward"`` from its start to its peak, ``"return"`` from its peak to its end.

    A whole repetition is two movements (out and back; the speed is zero at the peak), so
    its SPARC and LDLJ are lower than those of one reach; the phases are single movements,
    comparable with point-to-point figures in the literature.
    """
    if phase not in _SPANS:
        raise InvalidArgument(f"phase must be one of {list(_SPANS)}, got {phase!r}")
    return tuple(angle_smoothness(angle, t, *_SPANS[phase](r), params) for r in repetitions)


_SPANS = {
    "whole": lambda r: (r.start_s, r.end_s),
    "outward": lambda r: (r.start_s, r.peak_s),
    "return": lambda r: (r.peak_s, r.end_s),
}


def _profile(speed: np.ndarray, fs: float, minimum: int) -> np.ndarray:
    v = np.asarray(speed, dtype=float)
    if v.ndim != 1 or v.size < minimum:
        raise InvalidShape(f"speed must have shape (N,) with N ≥ {minimum}, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise InvalidArgument("speed must be finite (cut a movement at its missing samples)")
    if not fs > 0:
        raise InvalidArgument(f"fs must be > 0 Hz, got {fs!r}")
    if not np.any(v):
        raise InvalidArgument("speed is zero throughout: no movement to measure")
    return v
