"""Joint-angle profiles with exact derivatives.

After the thesis's simulator (Lovato 2024, App. B.2): a joint's angular rate is a sum of
Gaussian pulses, ``ω(t) = A / (σ √(2π)) · exp(-(t - t0)² / (2σ²))``; a pulse moves the
joint by ``A``, so a pulse up and one down later make a smooth trapezoid (the thesis uses
``σ = 0.5 s``). Here a profile is a sum of such *ramps* (the pulse's integral,
``A · Φ((t - t0) / σ)``) and optional sinusoids, each with its rate and acceleration in
closed form, so the IMU synthesis needs no numerical differentiation.

Angles in radians, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from ..errors import InvalidArgument

_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


@dataclass(frozen=True)
class Ramp:
    """A smooth step of ``amplitude`` [rad] centred at ``t0`` [s]; its rate is a Gaussian
    pulse of standard deviation ``sigma`` [s] (the step takes about ``4 sigma``)."""

    t0: float
    amplitude: float
    sigma: float = 0.5

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise InvalidArgument(f"ramp sigma must be positive seconds, got {self.sigma!r}")


@dataclass(frozen=True)
class Sine:
    """``amplitude · sin(2π frequency t + phase)`` [rad], for sway and tremor."""

    amplitude: float
    frequency_hz: float
    phase: float = 0.0


@dataclass(frozen=True)
class Excursion:
    """One excursion of a joint from rest and back, as planned: up by ``amplitude`` [rad]
    on a ramp centred at ``up_s`` [s], back down on one centred at ``down_s`` [s], both of
    standard deviation ``sigma`` [s]. ``held``: a posture held while another joint
    exercises (the elbow at 90° for pronation), not a repetition of its own.

    The ground truth of what a repetition counter and a range of motion should find: the
    joint's rate is the two Gaussian pulses, so times and speeds are in closed form."""

    up_s: float
    down_s: float
    amplitude: float
    sigma: float
    held: bool = False

    @property
    def peak_s(self) -> float:
        """Middle of the plateau [s]."""
        return 0.5 * (self.up_s + self.down_s)

    @property
    def peak_value(self) -> float:
        """The excursion's value at its peak, from rest [rad]: ``amplitude`` times
        Φ(d/2σ) − Φ(−d/2σ) for ramps ``d`` apart (the ramps' tails overlap: 2 s apart at
        σ = 0.25 s reach 99.994 % of the amplitude)."""
        half = 0.5 * (self.down_s - self.up_s) / self.sigma
        return float(self.amplitude * (ndtr(half) - ndtr(-half)))

    def onset_s(self, speed_fraction: float) -> tuple[float, float]:
        """Where the speed is ``speed_fraction`` of its peak, before the rise and after
        the return [s] (a Gaussian pulse falls to f of its peak at ±σ·√(2 ln(1/f)))."""
        if not 0.0 < speed_fraction < 1.0:
            raise InvalidArgument(f"speed_fraction must be in (0, 1), got {speed_fraction}")
        inset = self.sigma * np.sqrt(2.0 * np.log(1.0 / speed_fraction))
        return self.up_s - inset, self.down_s + inset

    @property
    def peak_speed(self) -> float:
        """Peak angular speed [rad/s] (the pulses do not overlap: ≥ 4σ apart)."""
        return abs(self.amplitude) * _INV_SQRT_2PI / self.sigma


@dataclass(frozen=True)
class Profile:
    """An angle over time: ``offset`` + ramps + sines [rad]; ``excursions``: what the
    ramps of :func:`hold_and_return` and :func:`repetitions` mean (ground truth)."""

    offset: float = 0.0
    ramps: tuple[Ramp, ...] = ()
    sines: tuple[Sine, ...] = ()
    excursions: tuple[Excursion, ...] = ()

    def __add__(self, other: Profile) -> Profile:
        return Profile(self.offset + other.offset, self.ramps + other.ramps,
                       self.sines + other.sines, self.excursions + other.excursions)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Angle [rad], rate [rad/s] and acceleration [rad/s²] at times ``t`` (N,)."""
        t = np.asarray(t, dtype=float)
        q = np.full(t.shape, self.offset)
        dq = np.zeros(t.shape)
        ddq = np.zeros(t.shape)
        for ramp in self.ramps:  # a handful of terms; vectorised over time
            z = (t - ramp.t0) / ramp.sigma
            pulse = ramp.amplitude * _INV_SQRT_2PI * np.exp(-0.5 * z * z) / ramp.sigma
            q += ramp.amplitude * ndtr(z)
            dq += pulse
            ddq += -z / ramp.sigma * pulse
        for sine in self.sines:
            w = 2.0 * np.pi * sine.frequency_hz
            phase = w * t + sine.phase
            q += sine.amplitude * np.sin(phase)
            dq += sine.amplitude * w * np.cos(phase)
            ddq += -sine.amplitude * w * w * np.sin(phase)
        return q, dq, ddq

    def value_at(self, t: float) -> float:
        return float(self.evaluate(np.array([t]))[0][0])


def hold_and_return(start: float, amplitude: float, rise: float, hold: float,
                    sigma: float | None = None, held: bool = False) -> Profile:
    """One repetition: from rest up by ``amplitude`` [rad] starting at ``start`` [s], taking
    ``rise`` [s] (±3σ of the pulse), held ``hold`` [s], and back in ``rise`` [s]; ``held``:
    a posture kept for another joint's exercise, not a repetition (:class:`Excursion`)."""
    sigma = rise / 6.0 if sigma is None else sigma
    up = start + rise / 2.0
    down = up + rise + hold
    return Profile(ramps=(Ramp(up, amplitude, sigma), Ramp(down, -amplitude, sigma)),
                   excursions=(Excursion(up, down, amplitude, sigma, held),))


def repetitions(start: float, count: int, amplitude: float, rise: float = 1.5,
                hold: float = 0.5, rest: float = 1.0) -> Profile:
    """``count`` repetitions of :func:`hold_and_return`, ``rest`` [s] apart."""
    if count < 0:
        raise InvalidArgument(f"repetition count must be ≥ 0, got {count}")
    period = 2.0 * rise + hold + rest
    profile = Profile()
    for i in range(count):
        profile = profile + hold_and_return(start + i * period, amplitude, rise, hold)
    return profile


@dataclass(frozen=True)
class Motion:
    """Joint-angle profiles by name (``ANGLE_NAMES``), and the thorax's in the world:
    ``trunk_heading`` (about the vertical), ``trunk_flexion`` (forward bend),
    ``trunk_lateral`` (side bend toward the arm's side), ``trunk_rotation`` (axial)."""

    joints: dict[str, Profile] = field(default_factory=dict)
    trunk: dict[str, Profile] = field(default_factory=dict)

    def end_time(self) -> float:
        """The time [s] by which every ramp has settled (t0 + 4σ)."""
        ends = [r.t0 + 4 * r.sigma for p in (*self.joints.values(), *self.trunk.values())
                for r in p.ramps]
        return max(ends, default=0.0)
