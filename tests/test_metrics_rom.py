"""Range of motion: the api.md formula, robust extremes, windows, the angles that moved,
and the truth files' exercises (``recording_set``: the stand-ins' extremes from their
simulation, the shared files' from their README)."""

import numpy as np
import pytest
from armtrack.estimator.arm import NORMAL_RANGE_DEG, PAPER_RANGE_DEG, REPORTED_ANGLES
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.metrics import (
    RomParams,
    percent_of,
    range_of_motion,
    range_of_motion_table,
    rom_report,
)

DEG = np.pi / 180
CALIBRATION = [(0.0, 10.5)]  # the calibration poses, N-pose and T-pose, up to scoring

#: The recordings (the angles each moves and their exact extremes come from the set's
#: facts: the shared README, or the stand-in's simulation; ``recording_sets``).
NAMES = ["abduction_120", "elbow_6axis", "elbow_6axis_long", "elbow_flexion", "left_reach_50hz",
         "pronation", "shoulder_abduction", "shoulder_flexion", "trunk_reach", "wrist_flexion"]


def test_percent_of_normal_is_the_share_of_the_side_moved():
    """api.md: max(max ÷ normal_max, min ÷ normal_min) × 100, the second term only where
    normal_min < 0, clamped at 0; by hand."""
    # the spec's example: shoulder flexion to 150° of AAOS −60…180° reads 83 %, not 63 %
    assert percent_of(0.0, 150.0, (-60.0, 180.0)) == pytest.approx(150 / 180 * 100)
    assert percent_of(0.0, 120.0, (0.0, 150.0)) == pytest.approx(80.0)
    # extension is the side moved most: −45 of −60 = 75 % beats 30 of 180 = 17 %
    assert percent_of(-45.0, 30.0, (-60.0, 180.0)) == pytest.approx(75.0)
    # min ÷ normal_min only where normal_min < 0: a negative min of a 0…150 joint adds
    # nothing, and a session that stayed on the wrong side reads 0, not a negative share
    assert percent_of(-10.0, 60.0, (0.0, 150.0)) == pytest.approx(40.0)
    assert percent_of(-8.0, -2.0, (0.0, 150.0)) == 0.0
    # a reference with only a negative side (a target of −30…0) uses the min
    assert percent_of(-15.0, 5.0, (-30.0, 0.0)) == pytest.approx(50.0)
    assert percent_of(30.0, 60.0, None) is None
    t = np.arange(0, 10, 0.01)
    angle = np.interp(t, [0, 5, 10], [-40.0, 80.0, -40.0]) * DEG
    rom = range_of_motion("forearm_pronation", angle, t, params=RomParams(percentile=0))
    assert (rom.min_deg, rom.max_deg, rom.range_deg) == pytest.approx((-40.0, 80.0, 120.0))
    assert rom.percent_of_normal == pytest.approx(100.0)  # AAOS −80…80: 80 of 80
    assert rom.percent_of_paper == pytest.approx(80 / 90 * 100)  # Table 2 −90…90
    assert rom.to_report() == pytest.approx({
        "min": -40.0, "max": 80.0, "range": 120.0, "normal_min": -80.0, "normal_max": 80.0,
        "percent_of_normal": 100.0})


def test_a_short_spike_does_not_make_the_range():
    t = np.arange(0, 60, 0.01)
    angle = 30 * (1 - np.cos(2 * np.pi * t / 6)) / 2  # 0…30°, peaks every 6 s
    spiky = angle.copy()
    spiky[3000:3005] = 170.0  # 50 ms of nonsense
    robust = range_of_motion("elbow_flexion", spiky * DEG, t)
    exact = range_of_motion("elbow_flexion", spiky * DEG, t, params=RomParams(percentile=0))
    print(f"spike: robust range {robust.range_deg:.4f} deg (tail percentile "
          f"{robust.percentile:.4f} %), exact {exact.range_deg:.1f} deg")
    assert exact.max_deg == pytest.approx(170.0)
    # each tail holds 0.1 s of 60 s: q = 1/6 %; the 30° peaks are flat to < 0.01° there
    assert robust.percentile == pytest.approx(100 * 0.1 / 60, rel=1e-3)
    assert robust.range_deg == pytest.approx(30.0, abs=0.01)
    fixed = range_of_motion("elbow_flexion", spiky * DEG, t, params=RomParams(percentile=0.5))
    assert fixed.range_deg == pytest.approx(30.0, abs=0.1)


def test_one_repetition_in_a_long_session_keeps_its_peak():
    """Why the tails hold a time, not a fraction: a single 5-s repetition in 5 minutes."""
    t = np.arange(0, 300, 0.01)
    angle = np.where((t > 100) & (t < 105), 60 * (1 - np.cos(2 * np.pi * (t - 100) / 5)) / 2, 0)
    by_time = range_of_motion("wrist_flexion", angle * DEG, t)
    by_fraction = range_of_motion("wrist_flexion", angle * DEG, t,
                                  params=RomParams(percentile=0.5))
    print(f"one repetition of 60 deg in 300 s: range {by_time.range_deg:.3f} deg with 0.1-s "
          f"tails, {by_fraction.range_deg:.3f} deg with P0.5/P99.5")
    # 0.05 s (plus a sample) off each side of a 5-s raised cosine's peak: 60·(1 − cos(2πτ/5))/2
    tau = 0.05 + 0.01
    assert by_time.range_deg == pytest.approx(60.0, abs=60 * (1 - np.cos(2 * np.pi * tau / 5)) / 2)
    assert by_fraction.range_deg < 50.0


def test_windows_and_missing_samples(recording_set):
    """The calibration T-pose (90° abduction) is not exercise."""
    table = recording_set.truth("elbow_flexion")
    facts = recording_set.facts["elbow_flexion"]
    low, high = facts.extremes["elbow_flexion"]
    if facts.excursions is None:  # the shared file: raised cosines of 5 s from 11 s
        first = (11.0, 16.0)
    else:  # the stand-in's first repetition, ±5σ around its ramps: at rest there within
        e = facts.excursions["elbow_flexion"][0]  # 120°·Φ(−5) = 3e-5° (next ramp 10σ on)
        first = (e.up_s - 5 * e.sigma, e.down_s + 5 * e.sigma)
    t = table["t"]
    everything = range_of_motion("shoulder_abduction", table["shoulder_abduction"] * DEG, t)
    exercise = range_of_motion("shoulder_abduction", table["shoulder_abduction"] * DEG, t,
                               exclude=CALIBRATION)
    print(f"{recording_set.source} shoulder_abduction on elbow_flexion: "
          f"{everything.range_deg:.2f} deg with the "
          f"calibration, {exercise.range_deg:.2f} deg without")
    assert everything.moved and everything.range_deg == pytest.approx(90.0, abs=0.01)
    assert not exercise.moved and exercise.range_deg == 0.0
    marked = range_of_motion("elbow_flexion", table["elbow_flexion"] * DEG, t,
                             include=[first], params=RomParams(percentile=0))
    assert (marked.min_deg, marked.max_deg) == pytest.approx((low, high), abs=1e-4)
    lossy = table["elbow_flexion"] * DEG
    lossy[::2] = np.nan
    half = range_of_motion("elbow_flexion", lossy, t, exclude=CALIBRATION)
    assert half.samples == np.count_nonzero(t >= 10.5) // 2
    assert half.range_deg == pytest.approx(high - low, abs=0.01)


@pytest.mark.parametrize("name", NAMES)
def test_truth_files_moved_angles_and_their_range(recording_set, name):
    table = recording_set.truth(name)
    moved = recording_set.facts[name].extremes
    angles = {k: table[k] * DEG for k in REPORTED_ANGLES}
    rom = range_of_motion_table(angles, table["t"], exclude=CALIBRATION)
    print(f"{recording_set.source} {name}: " + "; ".join(
        f"{k} {v.min_deg:.3f}…{v.max_deg:.3f} = {v.range_deg:.3f} deg, "
        f"{v.percent_of_normal:.2f} % of AAOS, {v.percent_of_paper or float('nan'):.2f} % "
        f"of Table 2" for k, v in rom.items()))
    assert list(rom) == [k for k in REPORTED_ANGLES if k in moved]
    for angle, (low, high) in moved.items():
        r = rom[angle]
        # 0.1 s of samples per tail, spread over the peaks at that extreme (≥ 3 of
        # raised cosines ≥ 4 s long): ≤ 0.05/3 s, plus a sample (≤ 20 ms), off each side
        # of a peak of amplitude A costs A·(1 − cos(2π·τ/4))/2; the files print 1e-5°
        # (the stand-ins' peaks are flatter: a 0.5-s hold between Gaussian ramps)
        def bound(a):
            return abs(a) * (1 - np.cos(2 * np.pi * (0.05 / 3 + 0.02) / 4)) / 2 + 1e-5
        assert r.min_deg == pytest.approx(low, abs=bound(low))
        assert r.max_deg == pytest.approx(high, abs=bound(high))
        normal = NORMAL_RANGE_DEG[angle]
        assert (r.normal_min_deg, r.normal_max_deg) == normal
        # the side rule from the truth's own extremes (shoulder flexion 0…150 of −60…180:
        # 83.3 %), within what the robust extremes may miss of them
        def side_rule(reference, low=low, high=high):
            shares = [high / reference[1]] + ([low / reference[0]] if reference[0] < 0 else [])
            return max(0.0, *shares) * 100

        assert r.percent_of_normal == pytest.approx(
            side_rule(normal), abs=100 * max(bound(low), bound(high)) / 10)
        paper = PAPER_RANGE_DEG.get(angle)
        assert r.percent_of_paper == (None if paper is None else pytest.approx(
            side_rule(paper), abs=100 * max(bound(low), bound(high)) / 10))
    report = rom_report(rom)
    assert all(set(v) == {"min", "max", "range", "normal_min", "normal_max",
                          "percent_of_normal"} for v in report.values())
    everything = range_of_motion_table(angles, table["t"], exclude=CALIBRATION,
                                       moved_only=False)
    assert list(everything) == list(REPORTED_ANGLES)
    assert everything["clavicle_elevation"].percent_of_normal is None


def test_moved_threshold():
    t = np.arange(0, 20, 0.01)
    small = 9.0 * np.sin(2 * np.pi * t / 5) / 2  # a 9° range
    assert not range_of_motion("wrist_deviation", small * DEG, t).moved
    assert range_of_motion("wrist_deviation", small * DEG, t,
                           params=RomParams(moved_threshold=5 * DEG)).moved


def test_invalid_input():
    t = np.arange(0, 1, 0.01)
    with pytest.raises(InvalidArgument):
        range_of_motion("elbow", np.zeros(t.size), t)
    with pytest.raises(InvalidArgument):
        range_of_motion("elbow_flexion", np.full(t.size, np.nan), t)
    with pytest.raises(InvalidArgument):
        range_of_motion("elbow_flexion", np.zeros(t.size), t, include=[(5.0, 6.0)])
    with pytest.raises(InvalidShape):
        range_of_motion("elbow_flexion", np.zeros(3), t)
    with pytest.raises(InvalidArgument):
        range_of_motion_table({"elbow_residual": np.zeros(t.size)}, t)
    with pytest.raises(InvalidArgument):
        RomParams(percentile=60)
