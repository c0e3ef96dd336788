"""A forearm-only kit's heading held by the elbow's hinge against a virtual upper arm
(issue 19): the kit assumes the upper arm hangs still beside the trunk, so the forearm has
two degrees of freedom against the trunk (elbow flexion, pronation) and a 6-axis
heading drift shows as a turn out of the hinge's plane, which the pipeline corrects as it
does between two sensors (``pipeline.constraints``). Samples that break the hinge by
more than a drift can (the T-pose, an arm raised: the assumption, not the heading) are
left out.

The case: a phone on the forearm through a 7-minute session of sets with rests, whose
gyroscope bias steps by up to 8 mrad/s an axis after the calibration poses (a phone
warming up in the hand). Without the hinge its pronation drifted to 5.4–13.2° RMSE
(seeds 0–3); the bar is the issue's 2°. In ``reach`` (the arm raised, the assumption
broken) its pronation was 0.5–3.4° without the hinge and must stay under the bar with it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from armtrack.estimator.pipeline import estimate_recording
from armtrack.estimator.recording import SensorStream
from armtrack.estimator.simulation import SCORED_FROM_S
from test_phone_kit_accuracy import BAR_DEG, phone_like

SEEDS = (0, 1, 2, 3)
#: The largest step of the bias per axis after the poses [rad/s].
WARM_UP_STEP = 0.008


def rmse_after_warm_up(exercise: str, seed: int) -> dict[str, float]:
    recording, truth, _ = phone_like(exercise, "forearm", seed)
    stream = recording.sensors["forearm"]
    step = np.random.default_rng(seed).uniform(-WARM_UP_STEP, WARM_UP_STEP, 3)
    gyr = stream.gyr + (stream.t[:, None] > 11.0) * step  # after the poses
    recording = replace(recording, sensors={"forearm": SensorStream(
        t=stream.t, acc=stream.acc, gyr=gyr, mag=None)})
    estimates, _ = estimate_recording(recording)
    scored = estimates.t >= SCORED_FROM_S
    out = {}
    for angle in ("elbow_flexion", "forearm_pronation"):
        expected = np.rad2deg(np.interp(estimates.t[scored], truth.t, truth.angles[angle]))
        error = estimates.degrees()[angle][scored] - expected
        out[angle] = float(np.sqrt(np.mean(error**2)))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("exercise", ["long_session", "reach"])
def test_forearm_phone_holds_its_heading_through_a_long_session(exercise):
    """``reach`` raises the arm (the assumption broken: its elbow flexion is not the
    truth's and is not scored); the hinge must not turn its pronation for it."""
    figures = [rmse_after_warm_up(exercise, seed) for seed in SEEDS]
    for angle in ("elbow_flexion", "forearm_pronation"):
        print(f"\nforearm phone, {exercise}, bias stepping after the poses: {angle} RMSE "
              + ", ".join(f"{f[angle]:.2f}°" for f in figures) + f" (seeds {SEEDS})")
    assert max(f["forearm_pronation"] for f in figures) < BAR_DEG
    if exercise == "long_session":
        assert max(f["elbow_flexion"] for f in figures) < BAR_DEG
