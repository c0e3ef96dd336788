"""Whether a forearm sensor's turn was the elbow's: the radius it turned about.

A phone on the forearm alone cannot see the elbow's angle: it sees the forearm turn. An
elbow flexion turns the forearm about the elbow, a few tenths of a metre at most from the
sensor (the phone sits 0.1–0.2 m from the elbow); a forward raise of the straight arm
turns it about the same axis, but about the shoulder, the upper arm's length further
(0.3–0.6 m). From the angles alone the two are one movement (``assumptions.py``: the
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

Where the two lie depends on the body: the phone is ``PHONE_ON_FOREARM`` of the forearm's
length from the elbow, the shoulder the upper arm's length further. The threshold
(``pivot_m``) is halfway between, from the session's segment lengths (measured, or from
the patient's height, ``body.py``): 0.23 m for a 1.2 m patient, 0.33 m for 1.75 m, 0.37 m
for 1.95 m. One 0.34 m for every body let a 1.2 m patient's raises (0.33–0.35 m) count.
On the simulator (a phone at 60 Hz with phone-like errors, ``phone_like`` of
``tests/test_phone_kit_accuracy.py``; seeds 0–3, both arms, 5 repetitions each; measured
by hand, prod19) the radii are, elbow flexions / slow elbow flexions with a 0.2 m/s²
offset / straight-arm raises: 1.2 m 0.11–0.13 / 0.08–0.14 / 0.33–0.35 (threshold 0.23);
1.75 m 0.16–0.18 / 0.13–0.20 / 0.49–0.51 (0.33); 1.95 m 0.18–0.20 / 0.15–0.22 /
0.54–0.57 (0.37). ``tests/test_elbow_pivot_body.py`` holds seeds 0–2 of the small and the
tall body; the report's and the phone's tests stream a 1.2 m patient's raise through a
server, the live page's feeds trails for small and tall bodies. The phone's place on
the forearm is not known: halfway leaves half the upper arm's length (9 % of the
height) either way. With the phone at 0.35, 0.5
and 0.95 of the forearm (seeds 0–1, both arms, 1.2/1.75/1.95 m, by hand) every flexion
and raise was still told right (at 0.35 on a 1.2 m body: 0.05–0.07 / 0.28–0.29 m, at
0.95: 0.16–0.17 / 0.38–0.40 m); a phone strapped right at the elbow would count a raise.
A movement slower than ``MIN_RATE`` (peak ``ω⊥``) pulls too little to tell (``ω⊥² r``
under the accelerometer's and the tilt's errors) and is not judged: it counts as the
elbow's, as before.

``split_elbow_repetitions`` is the one rule: the report, the phone's count
(``server/ingest/feedback.py``) and the therapist's live page (``server/live/motion.py``)
each call it with the turn terms they hold and the session's body.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..body import SegmentLengths
from .repetitions import Repetition

#: Where a phone on the forearm sits: this share of the forearm's length from the elbow
#: (strapped on the forearm's outer side, as the simulator puts a forearm sensor,
#: ``simulation/imu.py``'s ``default_mount``).
PHONE_ON_FOREARM = 0.65
#: Peak rate across the forearm [rad/s] below which a turn is too slow to judge.
MIN_RATE = 1.0
#: Standard gravity [m/s²] (what a resting accelerometer reads).
G = 9.81


def pivot_m(lengths: SegmentLengths) -> float:
    """The radius [m] beyond which a forearm phone's turn is not the elbow's but the
    shoulder's (the arm raised straight), for a body of segment ``lengths``: halfway
    between the phone's distance to the elbow (``PHONE_ON_FOREARM`` of the forearm) and
    to the shoulder (the upper arm further)."""
    elbow = PHONE_ON_FOREARM * lengths.forearm
    return elbow + 0.5 * lengths.upper_arm


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


def split_elbow_repetitions(reps: Sequence[Repetition], t: np.ndarray, pull: np.ndarray,
                            across: np.ndarray, lengths: SegmentLengths
                            ) -> tuple[list[Repetition], list[tuple[Repetition, float]]]:
    """``reps`` of a forearm-only kit's elbow flexion, split into the elbow's own (kept)
    and those the forearm made turning about a point further than ``pivot_m(lengths)``
    — the shoulder, the arm straight — with that radius [m]. ``t`` [s] (N,) the times of
    the turn terms ``pull`` [m/s²] and ``across`` [rad²/s²] (N,) (``turn_terms``; NaN:
    none at that time); a repetition takes those from its start to its end, both
    included. The one rule of the report, the phone and the live page."""
    threshold = pivot_m(lengths)
    kept: list[Repetition] = []
    refused: list[tuple[Repetition, float]] = []
    for rep in reps:
        a = int(np.searchsorted(t, rep.start_s, "left"))
        b = int(np.searchsorted(t, rep.end_s, "right"))
        radius = fit_radius(pull[a:b], across[a:b])
        if radius is not None and radius > threshold:
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
    patient's (1.95 m, phone tilted 14°) past the 0.34 m then used for every body."""
    if sensor_y is None:
        return segment_up[:, 1]
    return segment_up @ np.asarray(sensor_y, dtype=float)
