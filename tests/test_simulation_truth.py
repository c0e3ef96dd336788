"""The simulator's truth of what a session holds: each joint's planned excursions
(repetitions and held postures), their times, peak values and speeds in closed form,
against the profiles they describe."""

import numpy as np
import pytest
from armtrack.estimator.simulation import (
    EXERCISES,
    Excursion,
    Ramp,
    SimulationConfig,
    exercise_motion,
    hold_and_return,
    repetitions,
    simulate,
)

DEG = np.pi / 180


@pytest.mark.parametrize("hold", [0.0, 0.5, 1.0, 20.0])
def test_an_excursion_describes_its_profile(hold):
    """Peak value, peak time, peak speed and the 10%-speed onsets, against the profile
    evaluated on a 1-ms grid."""
    profile = hold_and_return(3.0, 70 * DEG, 1.5, hold)
    (e,) = profile.excursions
    t = np.arange(0.0, 3.0 + 3.0 + hold + 3.0, 0.001)
    q, dq, _ = profile.evaluate(t)
    print(f"hold {hold} s: peak {np.rad2deg(e.peak_value):.5f}° at {e.peak_s:.3f} s, "
          f"onsets {e.onset_s(0.1)}, peak speed {np.rad2deg(e.peak_speed):.2f}°/s")
    assert e.peak_value == pytest.approx(profile.value_at(e.peak_s), abs=1e-12)
    assert e.peak_value == pytest.approx(q.max(), abs=1e-9)
    if hold <= 1.0:  # a longer plateau is flat to the float's precision
        assert abs(t[np.argmax(q)] - e.peak_s) <= 0.001
    if hold > 0:  # pulses ≥ 4σ apart: the peak speed is one pulse's
        assert e.peak_speed == pytest.approx(np.abs(dq).max(), rel=1e-3)
        start, end = e.onset_s(0.1)
        speed_at = np.interp([start, end], t, np.abs(dq))
        assert speed_at == pytest.approx([0.1 * e.peak_speed] * 2, rel=1e-3)
    with pytest.raises(ValueError):
        e.onset_s(1.5)


def test_repetitions_are_excursions_and_holds_are_marked():
    reps = repetitions(11.0, 3, -40 * DEG)
    # peaks at start + rise + hold / 2, 4.5 s apart
    assert [round(e.peak_s, 6) for e in reps.excursions] == [12.75, 17.25, 21.75]
    assert all(not e.held and e.amplitude == -40 * DEG for e in reps.excursions)
    held = hold_and_return(0.0, 90 * DEG, 1.5, 10.0, held=True)
    assert held.excursions[0].held
    both = reps + held
    assert len(both.excursions) == 4 and len(both.ramps) == 8


def test_the_elbow_held_keeps_its_ramps():
    """wrist_flexion's elbow at 90°, now a held excursion, has the ramps it had
    (centred 0.75 s after the start and after the last repetition, σ 0.375 s)."""
    motion = exercise_motion("wrist_flexion")
    elbow = motion.joints["elbow_flexion"]
    end = 11.0 + 2.0 + 2 * 3 * 4.5
    assert elbow.ramps == (Ramp(11.75, 90 * DEG, 0.375), Ramp(end + 0.75, -90 * DEG, 0.375))
    assert elbow.excursions == (Excursion(11.75, end + 0.75, 90 * DEG, 0.375, held=True),)


@pytest.mark.parametrize(("exercise", "expected"), [
    ("wrist_flexion", {"elbow_flexion": (1, 0), "wrist_flexion": (6, 6)}),
    ("elbow_wrist", {"elbow_flexion": (7, 7), "wrist_flexion": (6, 6)}),
    ("long_session", {"elbow_flexion": (44, 40), "forearm_pronation": (36, 36),
                      "wrist_flexion": (36, 36)}),
    ("long_concurrent", {"elbow_flexion": (40, 40), "forearm_pronation": (36, 36),
                         "wrist_flexion": (36, 36)}),
    ("trunk_reach", {"shoulder_flexion": (5, 5), "elbow_flexion": (5, 5)}),
])
def test_a_simulation_knows_its_repetitions(exercise, expected):
    """Truth.excursions: (excursions, repetitions) per joint; the calibration poses are
    none of them."""
    truth = simulate(SimulationConfig(exercise=exercise, tail_s=0.5)).truth
    got = {k: (len(v), len(truth.repetitions(k))) for k, v in truth.excursions.items()}
    assert got == expected
    for angle, excursions in truth.excursions.items():
        values = np.rad2deg(truth.angles[angle])
        for e in excursions:  # the truth series at each planned peak
            i = int(np.argmin(np.abs(truth.t - e.peak_s)))
            assert values[i] == pytest.approx(np.rad2deg(e.peak_value), abs=1e-3)
        assert all(e.up_s >= 10.5 for e in excursions)


def test_long_concurrent_overlaps_its_exercises_without_holding():
    motion = exercise_motion("long_concurrent")
    assert "long_concurrent" in EXERCISES
    elbow, pronation = (motion.joints[k].excursions for k in ("elbow_flexion",
                                                              "forearm_pronation"))
    # pronation's first repetition starts while the elbow's first is up
    assert elbow[0].up_s < pronation[0].up_s < elbow[0].down_s
    assert not any(e.held for p in motion.joints.values() for e in p.excursions)
