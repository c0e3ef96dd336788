"""Data quality of a session: sensors, sample rates, lost samples, magnetometer
disturbances, the calibration used and the warnings.

* **Lost samples** per sensor, from its time stamps (``estimator.sampling``): with
  ``dt`` the typical interval per sample, a gap of ``g`` seconds after a packet of ``k``
  samples (equal stamps: packed samples) holds ``round(g / dt) − k`` missing samples
  (jitter of a fraction of ``dt`` counts nothing).
* **Gaps** per sensor: intervals between time stamps over ``k − 1 + GAP_STEPS`` typical
  intervals (data lost in bulk, a sensor that stalled, or a clock that jumped forward),
  each with its start and end, and a warning naming them.
* **Magnetometer disturbance** (9-axis sensors): the field strength ``|m|`` against its
  median over the session; a sample is disturbed when it is more than
  ``MAG_TOLERANCE`` (15%) off (the Earth's field is 25–65 µT and steady; iron or a motor
  nearby changes its strength). Runs shorter than ``MAG_MIN_S`` are noise; runs closer
  than ``MAG_MERGE_S`` are one period. The heading of a 9-axis estimate is doubtful in
  those periods.
"""

from __future__ import annotations

import numpy as np
from armtrack.estimator.metrics import detect_repetitions
from armtrack.estimator.metrics.elbow_pivot import pivot_m
from armtrack.estimator.metrics.timebase import runs
from armtrack.estimator.sampling import packets, sample_interval_s, summarise_sampling

from ..ingest.carried_on import carries_on
from .content import (
    CalibrationQuality,
    PoseOut,
    Quality,
    SensorQuality,
    SessionData,
    Window,
    finite,
)
from .words import calibration_words

#: Relative deviation of |m| from its median that counts as a disturbance [-].
MAG_TOLERANCE = 0.15
#: Shorter disturbed runs are ignored [s].
MAG_MIN_S = 0.2
#: Disturbed runs closer than this are merged [s].
MAG_MERGE_S = 0.5
#: A sensor's time stamps further apart than this many median intervals make a gap [-].
GAP_STEPS = 5
#: Estimates further apart than this make a gap [s].
ESTIMATE_GAP_S = 0.25


def lost_samples(t: np.ndarray) -> tuple[int, float | None]:
    """Missing samples of a sensor's time stamps ``t`` [s] (N,), and its rate [Hz]
    (``None`` without two distinct stamps)."""
    timing = summarise_sampling(t)
    return timing.lost, (timing.rate_hz or None)


def time_gaps(t: np.ndarray) -> list[tuple[float, float]]:
    """Gaps ``(start_s, end_s)`` of a sensor's time stamps ``t`` [s] (N,): intervals after
    a packet of ``k`` samples over ``k − 1 + GAP_STEPS`` typical intervals."""
    step = sample_interval_s(t)
    if not step > 0:
        return []
    u, k = packets(t)
    far = np.flatnonzero(np.diff(u) > (k[:-1] - 1 + GAP_STEPS) * step)
    return [(float(u[i]), float(u[i + 1])) for i in far]


def magnetic_disturbances(t: np.ndarray, mag: np.ndarray) -> list[tuple[float, float]]:
    """Periods ``(start_s, end_s)`` where ``|mag|`` (N, 3) [µT] is off its median."""
    strength = np.linalg.norm(mag, axis=1)
    ok = np.isfinite(strength)
    if not np.any(ok):
        return []
    usual = float(np.median(strength[ok]))
    if usual <= 0:
        return []
    off = ok & (np.abs(strength - usual) > MAG_TOLERANCE * usual)
    periods: list[list[float]] = []
    for a, b in zip(*runs(off), strict=True):
        start, end = float(t[a]), float(t[b - 1])
        if periods and start - periods[-1][1] < MAG_MERGE_S:
            periods[-1][1] = end
        else:
            periods.append([start, end])
    return [(a, b) for a, b in periods if b - a >= MAG_MIN_S]


def quality(data: SessionData) -> Quality:
    session = data.session
    sensors = []
    warnings = []
    for name, stream in data.recording.sensors.items():
        lost, rate = lost_samples(stream.t)
        gaps_s = time_gaps(stream.t)
        if gaps_s:
            longest = max(gaps_s, key=lambda g: g[1] - g[0])
            warnings.append(f"sensor {name}: {len(gaps_s)} gap(s) in its time stamps, the "
                            f"longest {longest[1] - longest[0]:.2f} s from {longest[0]:.2f} s "
                            "(data lost, a stalled sensor or a clock that jumped forward)")
        duration = float(stream.t[-1] - stream.t[0]) if len(stream.t) > 1 else 0.0
        disturbed = (magnetic_disturbances(stream.t, stream.mag)
                     if stream.mag is not None else [])
        sensors.append(SensorQuality(
            name=name, nine_axis=stream.mag is not None, samples=len(stream.t),
            rate_hz=finite(rate, 2), duration_s=finite(duration, 2), lost_samples=lost,
            lost_percent=finite(100.0 * lost / max(1, lost + len(stream.t)), 2),
            gaps=[Window(start_s=finite(a), end_s=finite(b)) for a, b in gaps_s],
            magnetic_disturbances=[Window(start_s=finite(a), end_s=finite(b))
                                   for a, b in disturbed],
            magnetic_disturbance_s=finite(sum(b - a for a, b in disturbed), 2)))
    calibration = session.calibration or {}
    poses = [PoseOut(name=p["name"], start_s=finite(p["start"]), end_s=finite(p["end"]))
             for p in calibration.get("poses") or []]
    t = data.t
    gaps = []
    if t.size > 1:
        jumps = np.flatnonzero(np.diff(t) > ESTIMATE_GAP_S)
        gaps = [Window(start_s=finite(t[i]), end_s=finite(t[i + 1])) for i in jumps]
    excluded = (Window(start_s=finite(data.exclude[0][0]), end_s=finite(data.exclude[0][1]))
                if data.exclude else None)
    return Quality(
        sensors=sensors, estimates=int(t.size),
        estimate_rate_hz=finite(1.0 / step, 2) if (step := sample_interval_s(t)) > 0 else None,
        estimate_gaps=gaps,
        calibration=CalibrationQuality(
            method=calibration.get("method"),
            default_mounting=calibration.get("method") == "default",
            carries_on=carries_on(session),
            words=calibration_words(calibration.get("method"),
                                    [(p.name, p.start_s, p.end_s) for p in poses],
                                    carries_on(session)),
            final_time_s=finite(calibration.get("final_time_s")), poses=poses,
            excluded=excluded),
        estimator={str(k): str(v) for k, v in (session.estimator or {}).items()},
        warnings=list(calibration.get("warnings") or []) + warnings
        + shoulder_turn_warnings(data))


def shoulder_turn_warnings(data: SessionData) -> list[str]:
    """A sentence when a forearm-only kit's elbow flexion went out and back about the
    shoulder (the straight arm raised, ``estimator/metrics/elbow_pivot.py``): those
    movements are not counted as elbow repetitions."""
    if data.forearm_turns is None or "elbow_flexion" not in data.angles:
        return []
    reps = detect_repetitions(data.angles_rad["elbow_flexion"], data.t,
                              exclude=data.exclude or None)
    refused = data.elbow_split(reps)[1]
    if not refused:
        return []
    low, high = (f"{f(radius for _, radius in refused):.2f}" for f in (min, max))
    n = len(refused)
    threshold = pivot_m(data.recording.segment_lengths())
    return [f"{n} movement{'s' if n != 1 else ''} of the forearm phone (from "
            f"{refused[0][0].start_s:.1f} s) {'were' if n != 1 else 'was'} not counted as "
            f"elbow repetitions: the forearm turned about a point "
            f"{low if low == high else low + '–' + high} m away, the shoulder rather than "
            f"the elbow (the arm raised straight; for this patient's arm lengths, beyond "
            f"{threshold:.2f} m is not the elbow). A phone on the forearm counts the "
            "elbow's bending only; for shoulder raises the phone goes on the upper arm"]
