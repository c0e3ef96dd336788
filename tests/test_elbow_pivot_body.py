"""The elbow pivot's threshold follows the patient's body (``estimator/metrics/
elbow_pivot.py``, ``pivot_m``): a forearm phone's elbow flexions turn about the elbow,
its straight-arm raises about the shoulder, the upper arm's length further; where both
lie depends on the arm's lengths. One number for every body (0.34 m) let a small
patient's (1.2 m) raises count as elbow repetitions: they turn at 0.33–0.35 m.

On the project's simulator (a phone at 60 Hz with phone-like errors, ``phone_like``),
small and tall bodies, both arms, several seeds: every elbow flexion is kept (also slow
ones with the accelerometer 0.2 m/s² off along the phone, the elbow's hardest case), and
every raise is refused. Read through the one function the report, the phone and the
live page use (``split_elbow_repetitions``), on the report's inputs (the phone's
readings, its axis's upward component from the estimates and the calibration)."""

from __future__ import annotations

import numpy as np
import pytest
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.metrics import detect_repetitions
from armtrack.estimator.metrics.elbow_pivot import (
    pivot_m,
    split_elbow_repetitions,
    turn_terms,
    up_of_sensor_y,
)
from armtrack.estimator.pipeline import estimate_recording
from test_phone_kit_accuracy import phone_like

SEEDS = (0, 1, 2)
EXERCISE_FROM_S = 10.5  # after the calibration poses (the T-pose moves the elbow too)


def _split(exercise: str, seed: int, side: str, height_m: float, **kwargs):
    recording, _, _ = phone_like(exercise, "forearm", seed, 5, side=side, height_m=height_m,
                                 **kwargs)
    estimates, calibration = estimate_recording(recording)
    phone = recording.sensors["forearm"]
    y_up = np.interp(phone.t, estimates.t, up_of_sensor_y(
        estimates.R_world_segment["forearm"][:, 2, :],
        calibration.R_sensor_segment["forearm"][1]))
    reps = [r for r in detect_repetitions(estimates.angles["elbow_flexion"], estimates.t)
            if r.start_s > EXERCISE_FROM_S]
    assert len(reps) == 5, (exercise, seed, side, height_m, reps)
    return split_elbow_repetitions(reps, phone.t, *turn_terms(phone.acc[:, 1], phone.gyr, y_up),
                                   recording.segment_lengths())


@pytest.mark.parametrize("height_m", [1.2, 1.95])
def test_elbow_flexions_are_kept_and_raises_refused_for_small_and_tall_bodies(height_m):
    threshold = pivot_m(SegmentLengths.from_height(height_m))
    seen = []
    for case, exercise, kwargs in (
            ("elbow", "elbow_flexion", {}),
            ("slow elbow, offset", "elbow_flexion", {"acc_bias_y": 0.2, "slow": (3.5, 90.0)}),
            ("raise", "shoulder_flexion", {})):
        refused_radii = []
        for side in ("right", "left"):
            for seed in SEEDS:
                kept, refused = _split(exercise, seed, side, height_m, **kwargs)
                refused_radii += [r for _, r in refused]
                if case == "raise":
                    assert not kept and len(refused) == 5, (side, seed, kept)
                else:
                    assert len(kept) == 5 and not refused, (case, side, seed, refused)
        seen.append(f"{case}: {len(refused_radii)} refused" + (
            f" ({min(refused_radii):.3f}–{max(refused_radii):.3f} m)" if refused_radii else ""))
    print(f"\n{height_m} m, threshold {threshold:.3f} m: {'; '.join(seen)}")
