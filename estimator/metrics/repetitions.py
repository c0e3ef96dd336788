"""Repetitions: a full cycle out and back, counted once, as a therapist counts.

``detect_repetitions`` finds the *excursions* of one angle: one movement from the rest
position and back (the rule below). ``count_repetitions`` counts them as repetitions of
an exercise (``docs/programs.md``, "One repetition"): an exercise that moves one way from
rest (bend the elbow, raise the arm, reach) makes one excursion a repetition; one that
goes to both sides of its rest (``BOTH_WAYS``: turn the palm down, then up; bend the
wrist down, then up; turn the arm out, then in) makes a repetition of a turn to each
side, so its count is the number of turns to the side turned to more often.

Angles in [rad], times in [s], angular velocities in [rad/s]; ``Repetition`` also gives
its amplitude [deg] and peak velocity [deg/s] for reports.

The rule, on one angle series:

1. **Samples**: inside ``include`` windows (all when not given), outside ``exclude``
   windows (the calibration poses are not exercise), finite (a missing estimate is NaN).
   They are cut into stretches at gaps longer than ``max_gap_s``; each stretch is
   interpolated onto an even grid at its median rate (``timebase.uniform``) and
   low-passed at ``lowpass_hz`` (zero phase, ``velocity.lowpass``) against noise.
2. **Rest level** ``r(t)``: given, from rest windows, or the series' tracked mode
   (``rest.py``), so a drifting estimate keeps its rest.
3. **Hysteresis** on the excursion ``e = θ − r``: a sample is *at rest* while
   ``|e| < rest_band``; a run of samples with ``e ≥ rest_band`` (or ``e ≤ −rest_band``)
   is an *excursion*; it is a **repetition** when it reaches ``|e| ≥ min_amplitude``
   and is at rest just before and just after (an excursion cut by the start or end of a
   stretch is incomplete and not counted). So noise around the rest band's edge and
   wobbles smaller than ``min_amplitude`` are not counted, and a movement that turns
   back without reaching rest (0 → 120 → 60 → 120 → 0°) is one repetition. Each
   direction is an excursion of its own: wrist flexion then extension is two,
   ``direction`` +1 and −1 (one repetition of a both-ways exercise, ``count_repetitions``).
4. **Times**: the *peak* is the sample of largest ``|e|``. The *start* is the last rest
   sample before the excursion whose speed is at most ``onset_speed_fraction`` of the
   excursion's peak speed (searching back to the previous repetition's end); the *end*
   is the first such sample after it. Where the speed never falls that low, the band
   crossing is used. Movement time = end − start; the peak angular velocity is the
   largest ``|dθ/dt|`` of the smoothed angle between them.

Only repetitions and stretches are looped over, never samples.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument
from .rest import rest_by_mode, rest_from_windows
from .timebase import Windows, as_series, select, stretches, uniform
from .velocity import angular_velocity, lowpass

#: Angles whose exercises go to both sides of the rest position: the forearm's turn (palm
#: down, then up), the wrist's bend (down, then up) and side bend (toward the thumb, then
#: the little finger), the shoulder's rotation (hand out, then in). A repetition is a turn
#: to each side (``count_repetitions``); on every other angle it is one excursion.
BOTH_WAYS: frozenset[str] = frozenset(
    {"forearm_pronation", "wrist_flexion", "wrist_deviation", "shoulder_rotation"})


@dataclass(frozen=True)
class RepetitionParams:
    """Parameters of the repetition counter (module docstring)."""

    #: An excursion counts when its peak is at least this far from rest [rad]. 10°: above
    #: the noise, drift and crosstalk of a good estimate on an idle joint, below the
    #: smallest rehabilitation exercise of interest.
    min_amplitude: float = np.deg2rad(10.0)
    #: Within this of the rest level a sample is at rest [rad]: the hysteresis's lower
    #: threshold. 5°: many times the smoothed noise of an estimate (~0.2° after the
    #: low-pass for 0.5° white noise at 100 Hz) and half ``min_amplitude``.
    rest_band: float = np.deg2rad(5.0)
    #: Low-pass cut-off before counting [Hz]; ``None``: no filter. 3 Hz keeps the
    #: movement (rehabilitation repetitions are below 1–2 Hz) and removes sensor noise.
    lowpass_hz: float | None = 3.0
    #: Start and end are where the speed falls to this fraction of the excursion's peak
    #: speed [-]: 10%, a common movement-onset rule that stays above smoothed noise.
    onset_speed_fraction: float = 0.1
    #: Below this angular speed a sample is still, a candidate for the rest mode [rad/s].
    still_speed: float = np.deg2rad(5.0)
    #: Histogram bin for the rest mode [rad].
    mode_bin: float = np.deg2rad(1.0)
    #: Blocks over which a drifting rest level is tracked [s].
    drift_window_s: float = 20.0
    #: Gaps longer than this cut the series into stretches [s]; shorter gaps (lost
    #: samples, jitter) are interpolated over.
    max_gap_s: float = 0.25

    def __post_init__(self) -> None:
        if not 0.0 < self.rest_band < self.min_amplitude:
            raise InvalidArgument(
                f"need 0 < rest_band < min_amplitude [rad], got rest_band={self.rest_band!r}, "
                f"min_amplitude={self.min_amplitude!r}")
        if self.lowpass_hz is not None and not self.lowpass_hz > 0:
            raise InvalidArgument(f"lowpass_hz must be > 0 or None, got {self.lowpass_hz!r}")
        if not 0.0 < self.onset_speed_fraction < 1.0:
            raise InvalidArgument(
                f"onset_speed_fraction must be in (0, 1), got {self.onset_speed_fraction!r}")
        for name in ("still_speed", "mode_bin", "drift_window_s", "max_gap_s"):
            if not getattr(self, name) > 0:
                raise InvalidArgument(f"{name} must be > 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class Repetition:
    """One repetition of one angle. Times [s], angles [rad], velocity [rad/s]."""

    start_s: float
    peak_s: float
    end_s: float
    #: +1: away from rest in the angle's positive direction (flexion, abduction,
    #: pronation, ...), −1: negative (extension, supination, ...).
    direction: int
    #: The rest level at the peak [rad].
    rest: float
    #: The smoothed angle at the peak [rad].
    peak_angle: float
    #: ``|peak_angle − rest|`` [rad].
    amplitude: float
    #: Largest ``|dθ/dt|`` between start and end [rad/s].
    peak_velocity: float

    @property
    def movement_time_s(self) -> float:
        """End − start [s]."""
        return self.end_s - self.start_s

    @property
    def amplitude_deg(self) -> float:
        """The amplitude [deg], for reports."""
        return float(np.rad2deg(self.amplitude))

    @property
    def peak_velocity_deg_s(self) -> float:
        """The peak angular velocity [deg/s], for reports."""
        return float(np.rad2deg(self.peak_velocity))


def detect_repetitions(
    angle: np.ndarray,
    t: np.ndarray,
    *,
    include: Windows | None = None,
    exclude: Windows | None = None,
    rest_windows: Windows | None = None,
    rest_level: float | None = None,
    params: RepetitionParams | None = None,
) -> tuple[Repetition, ...]:
    """The repetitions of one angle series, in time order.

    ``angle``: [rad], shape (N,), NaN where there is no estimate; ``t``: [s], (N,),
    increasing. ``include`` / ``exclude``: windows ``(start_s, end_s)`` of samples to use /
    leave out. Rest level: ``rest_level`` [rad] if given, else from ``rest_windows`` (the
    samples there are used whatever ``include`` / ``exclude`` say), else the tracked mode
    of the used samples.
    """
    p = params or RepetitionParams()
    t, angle = as_series(t, angle)
    pieces = []
    for idx in stretches(t, select(t, include, exclude), np.isfinite(angle), p.max_gap_s):
        if np.count_nonzero(np.diff(t[idx])) < 2:  # fewer than 3 distinct times
            continue
        grid, values, rate = uniform(t[idx], angle[idx])
        smooth = lowpass(values, rate, p.lowpass_hz)
        pieces.append((grid, smooth, angular_velocity(smooth, rate)))
    if not pieces:
        return ()
    grid_all = np.concatenate([g for g, _, _ in pieces])
    if rest_level is not None:
        rest_all = np.full(grid_all.shape, float(rest_level))
    elif rest_windows is not None:
        rest_all = rest_from_windows(grid_all, t, angle, rest_windows)
    else:
        rest_all = rest_by_mode(
            grid_all, np.concatenate([y for _, y, _ in pieces]),
            np.concatenate([v for _, _, v in pieces]), band=p.rest_band,
            still_speed=p.still_speed, bin_width=p.mode_bin, drift_window_s=p.drift_window_s)
    found: list[Repetition] = []
    offset = 0
    for grid, smooth, velocity in pieces:
        rest = rest_all[offset:offset + grid.size]
        offset += grid.size
        found.extend(_in_stretch(grid, smooth, velocity, rest, p))
    return tuple(found)


def count_repetitions(excursions: Sequence[Repetition], both_ways: bool) -> int:
    """How many repetitions the ``excursions`` of one angle (``detect_repetitions``) are,
    as a therapist counts: a full cycle out and back, counted once.

    ``both_ways`` False (the exercise moves one way from rest: ``BOTH_WAYS`` does not hold
    its angle): each excursion is one. True: a repetition is a turn to each side of the
    rest, in either order; the count is the larger of the two sides' counts. Palm down and
    up ×5 is 5, so is palm down ×5 then up ×5; down ×5 and up ×3 is 5 (the range of motion
    says how far each side went); a patient who rests at one end (the palm down on a
    table) and turns to the other and back makes one excursion per repetition, all to one
    side: also one each. Counted live, the count goes up with the first turn of each
    repetition (the side that leads), never down."""
    if not both_ways:
        return len(excursions)
    positive = sum(1 for r in excursions if r.direction > 0)
    return max(positive, len(excursions) - positive)


def repetitions_by_angle(
    angles: Mapping[str, np.ndarray],
    t: np.ndarray,
    **kwargs,
) -> dict[str, tuple[Repetition, ...]]:
    """``detect_repetitions`` for each angle of ``angles`` (name → [rad] (N,)); the same
    keyword arguments for all."""
    return {name: detect_repetitions(values, t, **kwargs) for name, values in angles.items()}


def _in_stretch(grid: np.ndarray, smooth: np.ndarray, velocity: np.ndarray, rest: np.ndarray,
                p: RepetitionParams) -> list[Repetition]:
    """Repetitions in one evenly sampled stretch: times ``grid`` [s] (M,), smoothed angle
    [rad] (M,), its velocity [rad/s] (M,), the rest level [rad] (M,)."""
    n = grid.size
    excursion = smooth - rest
    state = np.where(excursion >= p.rest_band, 1, np.where(excursion <= -p.rest_band, -1, 0))
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(state)) + 1, [n]))
    starts, stops = bounds[:-1], bounds[1:]
    sign = state[starts]
    reach = np.maximum.reduceat(np.abs(excursion), starts)
    before_rest = (starts > 0) & (state[np.maximum(starts - 1, 0)] == 0)
    after_rest = (stops < n) & (state[np.minimum(stops, n - 1)] == 0)
    counted = np.flatnonzero((sign != 0) & before_rest & after_rest & (reach >= p.min_amplitude))
    speed = np.abs(velocity)
    out: list[Repetition] = []
    for j, k in enumerate(counted):  # loop over repetitions
        a, b = int(starts[k]), int(stops[k])
        previous_end = int(stops[counted[j - 1]]) if j > 0 else 0
        next_start = int(starts[counted[j + 1]]) if j + 1 < counted.size else n
        threshold = p.onset_speed_fraction * float(speed[a:b].max())
        before = np.flatnonzero((state[previous_end:a] == 0)
                                & (speed[previous_end:a] <= threshold))
        after = np.flatnonzero((state[b:next_start] == 0) & (speed[b:next_start] <= threshold))
        onset = previous_end + int(before[-1]) if before.size else a - 1
        offset = b + int(after[0]) if after.size else b
        peak = a + int(np.argmax(np.abs(excursion[a:b])))
        out.append(Repetition(
            start_s=float(grid[onset]), peak_s=float(grid[peak]), end_s=float(grid[offset]),
            direction=int(sign[k]), rest=float(rest[peak]), peak_angle=float(smooth[peak]),
            amplitude=float(abs(excursion[peak])),
            peak_velocity=float(speed[onset:offset + 1].max()),
        ))
    return out
