"""Single-sensor kits against ground truth (issue 19): a phone on the forearm alone, or on
the upper arm alone — 6-axis at 60 Hz with phone-like errors (gyroscope noise 0.01 rad/s,
bias up to 0.02 rad/s per axis, accelerometer noise 0.1 m/s², 2–5 ms jitter, repeated
time stamps, the phone turned up to 60° about the segment's long axis), calibration poses
then the exercise, through the whole estimator. The bar: 2° RMSE after the poses for
elbow flexion and pronation (forearm phone) and shoulder flexion, abduction and elevation
over a minute (upper-arm phone).

Each case prints its RMSE per seed (each seed draws its own mounting, biases, noise,
jitter and repeated stamps), on seeds 0–5 and again on seeds 6–15 that no tuning looked
at. The cases the estimator does not meet yet are marked
``xfail(strict=True)`` with the figures (issue 19's note); when they pass, the mark goes."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pytest
from armtrack.estimator.orientation import FILTERS, QcfParams, QuaternionComplementaryFilter
from armtrack.estimator.pipeline import estimate_recording
from armtrack.estimator.recording import SensorStream
from armtrack.estimator.simulation import SCORED_FROM_S, ImuErrors, SimulationConfig, simulate

BAR_DEG = 2.0
SEEDS = (0, 1, 2, 3, 4, 5)
#: The single-phone cases also run on seeds nobody looked at while the estimator was tuned
#: on 0–5 (issue 19's check that nothing was fitted to them).
UNSEEN_SEEDS = tuple(range(6, 16))
#: Share of readings stamped like the one before (phones deliver readings in bursts).
REPEATED_SHARE = 0.03


def phone_like(exercise: str, sensor: str, seed: int, repetitions: int | None = None,
               side: str = "right", gyro_bias_max: float = 0.02, height_m: float = 1.75,
               mount_tilt_deg: float = 8.0, acc_bias_y: float = 0.0,
               slow: tuple[float, float] | None = None):
    """A phone on ``sensor`` of the ``side`` arm doing ``exercise``; its recording with
    repeated stamps. (``gyro_bias_max`` 0: no bias; the same noise, mounting and stamps;
    ``height_m`` the patient's, ``mount_tilt_deg`` the phone's largest tilt off the arm,
    ``acc_bias_y`` [m/s²] its accelerometer's offset along its long axis; ``slow``: the
    single-joint exercise's repetitions taken (rise [s], amplitude [deg]) instead.)"""
    rng = np.random.default_rng(1000 + seed)
    config = SimulationConfig(
        exercise=exercise, sensors=(sensor,), side=side, rate_hz=60.0, nine_axis=False,
        seed=seed, height_m=height_m, mount_tilt_deg=mount_tilt_deg,
        errors=ImuErrors(gyro_noise=0.01, acc_noise=0.1, acc_bias=(0.0, acc_bias_y, 0.0)),
        gyro_bias_max=gyro_bias_max,
        jitter_s=float(rng.uniform(0.002, 0.005)), mount_axial_deg=60.0,
        repetitions=repetitions)
    motion = None
    if slow is not None:
        from armtrack.estimator.simulation.profiles import Motion
        from armtrack.estimator.simulation.profiles import repetitions as reps_of
        from armtrack.estimator.simulation.scenarios import EXERCISE_START_S, exercise_motion
        base = exercise_motion(exercise, repetitions_count=repetitions)
        rise, amplitude = slow
        motion = Motion(joints={**base.joints, exercise: reps_of(
            EXERCISE_START_S, repetitions or 5, np.deg2rad(amplitude), rise=rise)},
            trunk=base.trunk)
    sim = simulate(config, motion=motion)
    stream = sim.recording.sensors[sensor]
    t = stream.t.copy()
    repeated = np.flatnonzero(rng.random(len(t)) < REPEATED_SHARE)
    repeated = repeated[repeated > 0]
    t[repeated] = t[repeated - 1]
    t = np.maximum.accumulate(t)
    recording = replace(sim.recording, sensors={
        sensor: SensorStream(t=t, acc=stream.acc, gyr=stream.gyr, mag=None)})
    return recording, sim.truth, len(repeated)


@functools.lru_cache(maxsize=256)
def _errors(exercise: str, sensor: str, seed: int, repetitions, side: str) -> dict:
    """Every angle's RMSE [°] against the truth after the poses (one run for all)."""
    recording, truth, _ = phone_like(exercise, sensor, seed, repetitions, side)
    estimates, _ = estimate_recording(recording)
    scored = estimates.t >= SCORED_FROM_S
    degrees = estimates.degrees()
    out = {}
    for angle, values in truth.angles.items():
        expected = np.rad2deg(np.interp(estimates.t[scored], truth.t, values))
        out[angle] = float(np.sqrt(np.mean((degrees[angle][scored] - expected) ** 2)))
    return out


def rmse(exercise: str, sensor: str, angle: str, seed: int, repetitions=None,
         side: str = "right") -> float:
    return _errors(exercise, sensor, seed, repetitions, side)[angle]


def _pending(reason: str):
    return pytest.mark.xfail(strict=True, reason=reason)


SIDE_RAISE_FLEXION = (
    "measured 1.2–2.7° (right arm) and 1.8–5.5° (left) over seeds 0–5, 1.6–7.1° and "
    "0.9–7.4° over seeds 6–15 (bar 2°; the sides differ by seed only, means 3.0° and "
    "3.2° over 0–15): in a side raise to 80° the spec's Z·X·Y flexion is tan(80°) = 5.7 "
    "times the heading error, and the heading drifts by up to 5° in the minute (the bias "
    "learnt from the poses' stillness at 0.01 rad/s noise is known to 0.1–2.5 mrad/s an "
    "axis). Even with the bias known exactly the gyroscope's noise alone gives 0.4–2.2° "
    "(test_side_raise_flexion_with_the_bias_known): no bias estimate reaches the bar on "
    "every seed")

CASES = [
    # forearm phone: elbow flexion and pronation, in both of its exercises
    ("elbow_flexion", "forearm", "elbow_flexion", None, ()),
    ("elbow_flexion", "forearm", "forearm_pronation", None, ()),
    ("pronation", "forearm", "elbow_flexion", None, ()),
    ("pronation", "forearm", "forearm_pronation", None, ()),
    # upper-arm phone: a minute of raises, forward and sideways
    ("shoulder_flexion", "upper_arm", "shoulder_flexion", 14, ()),
    ("shoulder_flexion", "upper_arm", "shoulder_abduction", 14, ()),
    ("shoulder_flexion", "upper_arm", "shoulder_elevation", 14, ()),
    ("shoulder_abduction", "upper_arm", "shoulder_flexion", 14, (_pending(SIDE_RAISE_FLEXION),)),
    ("shoulder_abduction", "upper_arm", "shoulder_abduction", 14, ()),
    ("shoulder_abduction", "upper_arm", "shoulder_elevation", 14, ()),
]


def test_phone_like_recordings_are_what_the_issue_asks():
    recording, _, repeated = phone_like("shoulder_flexion", "upper_arm", 0, repetitions=14)
    stream = recording.sensors["upper_arm"]
    steps = np.diff(stream.t)
    assert stream.mag is None and recording.rate_hz == 60.0
    assert repeated > 0 and np.sum(steps == 0) >= repeated * 0.9
    assert stream.t[-1] - 11.0 >= 60.0  # a minute of exercise after the poses


def _single_phone_params():
    return [pytest.param(*c[:4], marks=c[4], id=f"{c[1]}-{c[0]}-{c[2]}") for c in CASES]


@pytest.mark.slow
@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize(("exercise", "sensor", "angle", "repetitions"), _single_phone_params())
def test_single_phone_reaches_the_bar(exercise, sensor, angle, repetitions, side):
    figures = [rmse(exercise, sensor, angle, seed, repetitions, side) for seed in SEEDS]
    print(f"\n{side} {sensor} phone, {exercise}: {angle} RMSE "
          + ", ".join(f"{f:.2f}°" for f in figures) + f" (seeds {SEEDS})")
    assert max(figures) < BAR_DEG


@pytest.mark.slow
@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize(("exercise", "sensor", "angle", "repetitions"), _single_phone_params())
def test_single_phone_reaches_the_bar_on_unseen_seeds(exercise, sensor, angle, repetitions,
                                                      side):
    """The same cases on seeds 6–15, which no tuning looked at."""
    figures = [rmse(exercise, sensor, angle, seed, repetitions, side) for seed in UNSEEN_SEEDS]
    print(f"\n{side} {sensor} phone, {exercise}: {angle} RMSE "
          + ", ".join(f"{f:.2f}°" for f in figures) + " (seeds 6–15)")
    assert max(figures) < BAR_DEG


class _BiasKnown(QuaternionComplementaryFilter):
    """``qcf`` told the gyroscope has no bias (its estimate held at zero)."""

    def __init__(self):
        super().__init__(params=QcfParams(bias_max=1e-12))


FLEXION_FLOOR = (
    "measured 0.4–2.2° over seeds 0–15 (right 0.44–2.19°, left 0.50–2.13°; 1.79° at most "
    "over 0–5): the heading then drifts only by the gyroscope's noise (0.01 rad/s at 60 Hz, "
    "an angle random walk of 1.3 mrad/√s: 0.6° after a minute), and tan(80°) = 5.7 turns "
    "that into more than 2° of flexion on some seeds; a 6-axis phone on the upper arm alone "
    "has nothing else to hold its heading")


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=FLEXION_FLOOR)
def test_side_raise_flexion_with_the_bias_known(monkeypatch):
    """The floor under the side raise's flexion: the same recordings with no gyroscope bias,
    and the filter told so (the bias needs no learning). What is left is the gyroscope's
    noise integrated into the heading."""
    monkeypatch.setitem(FILTERS, "qcf", _BiasKnown)
    figures = {}
    for side in ("right", "left"):
        figures[side] = []
        for seed in (*SEEDS, *UNSEEN_SEEDS):
            recording, truth, _ = phone_like("shoulder_abduction", "upper_arm", seed, 14, side,
                                             gyro_bias_max=0.0)
            estimates, _ = estimate_recording(recording)
            scored = estimates.t >= SCORED_FROM_S
            expected = np.rad2deg(np.interp(estimates.t[scored], truth.t,
                                            truth.angles["shoulder_flexion"]))
            error = estimates.degrees()["shoulder_flexion"][scored] - expected
            figures[side].append(float(np.sqrt(np.mean(error ** 2))))
        print(f"\n{side} upper_arm phone, side raise, bias known: shoulder_flexion RMSE "
              + ", ".join(f"{f:.2f}°" for f in figures[side]) + " (seeds 0–15)")
    assert max(max(f) for f in figures.values()) < BAR_DEG


LONG_SESSION_FLEXION = (
    "measured 0.7–2.3° over seeds 0–5 (bar 2°): its sets of side raises to 75° (see the "
    "side raise's case); abduction and elevation hold")


@pytest.mark.slow
@pytest.mark.parametrize("angle", [
    "shoulder_abduction", "shoulder_elevation",
    pytest.param("shoulder_flexion", marks=_pending(LONG_SESSION_FLEXION))])
def test_upper_arm_phone_through_an_eleven_minute_session(angle):
    """Rounds of forward raises, side raises, rotations and elbow flexions with 20 s
    rests in the N-pose between sets (the rests teach the bias again)."""
    figures = [rmse("shoulder_sets", "upper_arm", angle, seed) for seed in SEEDS]
    rotation = [rmse("shoulder_sets", "upper_arm", "shoulder_rotation", seed)
                for seed in SEEDS]
    print(f"\nupper_arm phone, shoulder_sets (11 min): {angle} RMSE "
          + ", ".join(f"{f:.2f}°" for f in figures) + f" (seeds {SEEDS}); rotation "
          "(not in the issue's bar) " + ", ".join(f"{f:.2f}°" for f in rotation))
    assert max(figures) < BAR_DEG
