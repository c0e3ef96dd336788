"""Whether a forearm sensor's turn was the elbow's: the radius it turned about.

A phone on the forearm alone cannot see the elbow's angle: it sees the forearm turn. An
elbow flexion turns the forearm about the elbow, a few tenths of a metre at most from the
sensor (the phone sits 0.1–0.2 m from the elbow); a forward raise of the straight arm
turns it about the same axis, but about the shoulder, the upper arm's length further
(0.4–0.6 m). From the angles alone the two are one movement (``assumptions.py``: the
raise reads as elbow flexion). The accelerometer tells them apart: turning at ``ω``
about a point on the sensor's long axis ``Y`` (``+Y`` proximal) at a distance ``r``
pulls the sensor toward it, ``ω⊥² r`` along ``+Y`` (``ω⊥``: the rate about the axes
across the forearm; the turn about ``Y`` itself, pronation, pulls nothing), and
whatever else ``Y`` reads is gravity, ``g · Y_up`` (the upward component of the
sensor's own ``Y``: the estimated forearm's turned by the calibration's mounting,
``up_of_sensor_y``; the forearm's own axis is off by the phone's tilt on the arm). So
over a movement

    r = Σ (p − p̄) · (ω⊥² − m)  /  Σ (ω⊥² − m)²,   p = a_y − g · Y_up, m = mean ω⊥²,

the least-squares radius beside a constant (the accelerometer's offset along ``Y``).
On the simulator (a phone at 60 Hz with phone-like errors,
seeds 0–15, both arms, 5 repetitions each, measured by hand with ``phone_like`` of
``tests/test_phone_kit_accuracy.py``) the elbow flexions' repetitions read 0.04–0.27 m and
the straight-arm raises' 0.41–0.57 m read along the forearm's axis; along the phone's own
(seeds 0–3, both arms, review18) 0.16–0.18 m and 0.48–0.51 m, the true 0.17 and 0.49 m:
``PIVOT_M`` lies between. The report's test
(``tests/test_reports.py``, a straight-arm raise) streams seed 0 of each through a server.
A movement slower than ``MIN_RATE`` (peak ``ω⊥``) pulls too little to tell (``ω⊥² r``
under the accelerometer's and the tilt's errors) and is not judged: it counts as the
elbow's, as before.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .repetitions import Repetition

#: Radius [m] beyond which a forearm's turn is not the elbow's (the shoulder's, arm straight).
PIVOT_M = 0.34
#: Peak rate across the forearm [rad/s] below which a turn is too slow to judge.
MIN_RATE = 1.0
#: Standard gravity [m/s²] (what a resting accelerometer reads).
G = 9.81


def turn_radius(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, y_up: np.ndarray,
                start_s: float, end_s: float) -> float | None:
    """The radius [m] the forearm sensor turned about between ``start_s`` and ``end_s``
    [s]: ``t`` [s] (N,), ``acc`` [m/s²] and ``gyr`` [rad/s] (N, 3) in the sensor frame,
    ``y_up`` (N,) the upward component of its ``+Y`` axis. None when the turn was slower
    than ``MIN_RATE`` (nothing to tell it by) or there are no samples."""
    lo, hi = np.searchsorted(t, start_s, "left"), np.searchsorted(t, end_s, "right")
    if hi - lo < 3:
        return None
    return fit_radius(*turn_terms(acc[lo:hi, 1], gyr[lo:hi], y_up[lo:hi]))


def turn_terms(acc_y: np.ndarray, gyr: np.ndarray, y_up: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the pull along the forearm that is not gravity ``a_y − g · Y_up``
    [m/s²] and the squared rate across it ``ω⊥²`` [rad²/s²] (``fit_radius``'s terms)."""
    return acc_y - G * y_up, gyr[:, 0] ** 2 + gyr[:, 2] ** 2


def fit_radius(pull: np.ndarray, across: np.ndarray) -> float | None:
    """The least-squares radius [m] of samples' ``pull`` [m/s²] against ``across``
    (``ω⊥²``, [rad²/s²]) with a constant beside it; None when fewer than 3 or the peak
    rate is under ``MIN_RATE``. The constant takes the accelerometer's own offset along
    the phone (phones' read ±0.2 m/s² and more): without it, 0.2 m/s² turned a slow elbow
    flexion's (90° in 3.5 s, peak 1.1 rad/s) 0.17 m into 0.32–0.43 m (review18); the
    repetition's still ends tell it from the turn's pull."""
    ok = np.isfinite(pull) & np.isfinite(across)
    if np.count_nonzero(ok) < 3 or float(np.sqrt(across[ok].max())) < MIN_RATE:
        return None
    w2 = across[ok] - across[ok].mean()
    spread = float(np.sum(w2 * w2))
    if spread <= 0.0:
        return None
    return float(np.sum((pull[ok] - pull[ok].mean()) * w2) / spread)


def split_elbow_repetitions(reps: Sequence[Repetition], t: np.ndarray, acc: np.ndarray,
                            gyr: np.ndarray, y_up: np.ndarray
                            ) -> tuple[list[Repetition], list[tuple[Repetition, float]]]:
    """``reps`` of a forearm-only kit's elbow flexion, split into the elbow's own (kept)
    and those the forearm made turning about a point further than ``PIVOT_M`` — the
    shoulder, the arm straight — with that radius [m]. Arguments as ``turn_radius``."""
    kept: list[Repetition] = []
    refused: list[tuple[Repetition, float]] = []
    for rep in reps:
        radius = turn_radius(t, acc, gyr, y_up, rep.start_s, rep.end_s)
        if radius is not None and radius > PIVOT_M:
            refused.append((rep, radius))
        else:
            kept.append(rep)
    return kept, refused


def y_up_of_quats(q: np.ndarray, sensor_y: np.ndarray | None = None) -> np.ndarray:
    """The upward (world ``z``) component of the sensor's ``+Y`` axis from its segment's
    orientation quaternions ``q`` (N, 4) ``w, x, y, z`` (segment to world): ``R[2, :]``
    · ``sensor_y``, the sensor's ``+Y`` in the segment's frame (the calibration's
    ``R_sensor_segment[1]``; None: the segment's own ``+Y``, ``R[2, 1]``)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    row = np.column_stack([2.0 * (x * z - w * y), 2.0 * (y * z + w * x),
                           1.0 - 2.0 * (x * x + y * y)])
    return up_of_sensor_y(row, sensor_y)


def up_of_sensor_y(segment_up: np.ndarray, sensor_y: np.ndarray | None) -> np.ndarray:
    """The upward component of the sensor's ``+Y`` axis from the segment's rows
    ``R_world_segment[..., 2, :]`` (N, 3) and the sensor's ``+Y`` in the segment's frame
    ``sensor_y`` (3,) (None: the segment's ``+Y``). The accelerometer's ``Y`` is the
    sensor's, not the segment's: a phone tilted 8° on the forearm against the segment
    read its elbow flexions' radius 0.1 m too far (0.26 m for 0.16 m, review18), a tall
    patient's (1.95 m, phone tilted 14°) past ``PIVOT_M``."""
    if sensor_y is None:
        return segment_up[:, 1]
    return segment_up @ np.asarray(sensor_y, dtype=float)
