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
whatever else ``Y`` reads is gravity, ``g · Y_up`` (the forearm's long axis's upward
component, from the estimated orientation). So over a movement

    r = Σ (a_y − g · Y_up) · ω⊥²  /  Σ ω⊥⁴,

the least-squares radius. On the simulator (a phone at 60 Hz with phone-like errors,
seeds 0–15, both arms, 5 repetitions each, measured by hand with ``phone_like`` of
``tests/test_phone_kit_accuracy.py``) the elbow flexions' repetitions read 0.04–0.27 m and
the straight-arm raises' 0.41–0.57 m: ``PIVOT_M`` lies between. The report's test
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
    (``ω⊥²``, [rad²/s²]); None when fewer than 3 or the peak rate is under ``MIN_RATE``."""
    ok = np.isfinite(pull) & np.isfinite(across)
    if np.count_nonzero(ok) < 3 or float(np.sqrt(across[ok].max())) < MIN_RATE:
        return None
    w2 = across[ok]
    return float(np.sum(pull[ok] * w2) / np.sum(w2 * w2))


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


def y_up_of_quats(q: np.ndarray) -> np.ndarray:
    """The upward (world ``z``) component of a segment's ``+Y`` axis from its orientation
    quaternions ``q`` (N, 4) ``w, x, y, z`` (segment to world): ``R[2, 1]``."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return 2.0 * (y * z + w * x)
