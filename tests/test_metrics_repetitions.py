"""Repetition counting on the truth files (``recording_set``): against their exact counts
and amplitudes (the shared files' README; the stand-ins' simulation plan, times and speeds
in closed form), against noisy, drifting, lossy copies of them, and against synthetic
series whose repetitions are known in closed form."""

import numpy as np
import pytest
from armtrack.estimator.arm import REPORTED_ANGLES
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.metrics import (
    BOTH_WAYS,
    RepetitionParams,
    consistency,
    count_repetitions,
    detect_repetitions,
    repetitions_by_angle,
)

DEG = np.pi / 180
#: Scoring starts at 10.5 s; before it are the calibration poses (N-pose, T-pose).
EXERCISE = [(10.5, np.inf)]

#: The recordings; their repetitions as signed amplitudes [deg] are the set's facts
#: (``recording_sets``): every other angle has none (the elbow *held* at 90° during wrist
#: and forearm exercises is not a repetition).
NAMES = ["abduction_120", "elbow_6axis", "elbow_6axis_long", "elbow_flexion", "left_reach_50hz",
         "pronation", "shoulder_abduction", "shoulder_flexion", "trunk_reach", "wrist_flexion"]
#: On the noise-free truth the amplitude is measured from a rest level tracked on still
#: samples near rest, which sit at most ~0.5° above the true rest at the bottom of a
#: repetition (still = below 5°/s); their median is within 0.2°.
TRUTH_AMPLITUDE_TOL_DEG = 0.2


@pytest.fixture(scope="session")
def truth(recording_set):
    """name → (truth table, calibration windows of the recording's header, expected
    repetitions: angle → signed amplitudes [deg])."""
    def read(name):
        header = recording_set.path(name).read_text()[:1000]
        poses = next(line for line in header.splitlines()
                     if line.startswith("# calibration: "))[len("# calibration: "):]
        windows = {p.split()[0]: (float(p.split()[1]), float(p.split()[2]))
                   for p in poses.split(";")}
        return recording_set.truth(name), windows, recording_set.facts[name].repetitions
    return read


def signed_amplitudes(reps):
    return [r.direction * r.amplitude_deg for r in reps]


@pytest.mark.parametrize("name", NAMES)
def test_counts_on_every_truth_file(truth, name):
    table, _, expected_reps = truth(name)
    t = table["t"]
    found = repetitions_by_angle({k: table[k] * DEG for k in REPORTED_ANGLES}, t,
                                 include=EXERCISE)
    counts = {k: len(v) for k, v in found.items() if v}
    print(f"{name}: {counts}")
    assert counts == {k: len(v) for k, v in expected_reps.items()}
    for angle, expected in expected_reps.items():
        reps = found[angle]
        got = np.array(signed_amplitudes(reps))
        print(f"  {angle}: amplitudes {np.round(got, 2).tolist()}; movement times "
              f"{[round(r.movement_time_s, 2) for r in reps]} s; peak velocities "
              f"{[round(r.peak_velocity_deg_s, 1) for r in reps]} deg/s")
        assert np.all(np.isfinite(got))
        worst = np.abs(got - expected).max()
        assert worst < TRUTH_AMPLITUDE_TOL_DEG, f"{angle}: amplitude off by {worst:.3f} deg"
        starts = np.array([r.start_s for r in reps])
        peaks = np.array([r.peak_s for r in reps])
        ends = np.array([r.end_s for r in reps])
        assert np.all(starts >= 10.5) and np.all(starts < peaks) and np.all(peaks < ends)
        assert np.all(ends[:-1] <= starts[1:]), "repetitions overlap"


def closed_form(recording_set):
    """elbow_flexion's repetitions in closed form: (peak, start, end [s], peak speed
    [deg/s]) each. The shared file's are raised cosines 0 → 120° → 0 of 5 s from 11 s:
    peaks at 13.5 + 5k s, peak speed π·120/5 deg/s, and start/end where the speed is 10%
    of its peak: 5·asin(0.1)/(2π) s inside each 5-s repetition. A stand-in's are its
    simulation's planned excursions: Gaussian speed pulses, 10% of the peak speed at
    σ·√(2 ln 10) before the rise and after the return (``Excursion``)."""
    facts = recording_set.facts["elbow_flexion"]
    if facts.excursions is None:
        inset = 5 * np.arcsin(0.1) / (2 * np.pi)
        return [(13.5 + 5 * k, 11 + 5 * k + inset, 16 + 5 * k - inset, np.pi * 120 / 5)
                for k in range(len(facts.repetitions["elbow_flexion"]))]
    return [(e.peak_s, *e.onset_s(0.1), np.rad2deg(e.peak_speed))
            for e in facts.excursions["elbow_flexion"]]


def test_truth_repetitions_match_their_closed_form(truth, recording_set):
    table, _, _ = truth("elbow_flexion")
    reps = detect_repetitions(table["elbow_flexion"] * DEG, table["t"], include=EXERCISE)
    expected = closed_form(recording_set)
    assert len(reps) == len(expected)
    for k, (r, (peak, start, end, speed)) in enumerate(zip(reps, expected, strict=True)):
        print(f"rep {k}: start {r.start_s:.3f} peak {r.peak_s:.3f} end {r.end_s:.3f} s, "
              f"peak velocity {r.peak_velocity_deg_s:.3f} deg/s")
        # the grid is the samples' (10 ms): times to a sample, plus one for the filter
        assert abs(r.peak_s - peak) <= 0.011
        assert abs(r.start_s - start) <= 0.021
        assert abs(r.end_s - end) <= 0.021
        assert abs(r.peak_velocity_deg_s - speed) < 0.01 * speed


def test_counts_with_rest_from_the_npose_window(truth):
    """The N-pose of the calibration as the rest window gives the same counts."""
    for name in NAMES:
        table, windows, expected = truth(name)
        for angle, amplitudes in expected.items():
            reps = detect_repetitions(table[angle] * DEG, table["t"], include=EXERCISE,
                                      rest_windows=[windows["npose"]])
            assert signed_amplitudes(reps) == pytest.approx(amplitudes, abs=0.05), name


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_counts_hold_on_noisy_drifting_lossy_copies(truth, seed):
    """White noise 0.5°, a drift of 6° over the recording plus a 2° swell of 120 s period,
    2% of the samples lost (NaN) and 1 ms timestamp jitter: every count, direction and
    idle angle's zero holds. The amplitudes stay within 1.5° of the noise-free ones: noise
    alone moves them ≤ 0.45° and the swell, tracked between 20-s blocks, ≤ 0.5° (measured
    on seeds 0-4). A peak moves no further than the truth stays within 0.5° (3σ of the
    smoothed noise, σ ≈ 0.15°) of its peak value: ±0.1 s on a 5-s raised cosine, ±0.6 s
    on a stand-in's plateau held 1 s (measured: at most 0.85 of that, seeds 0-2)."""
    rng = np.random.default_rng(seed)
    worst = {}
    for name in NAMES:
        table, _, expected = truth(name)
        t_clean = table["t"]
        t = t_clean + rng.uniform(-0.001, 0.001, t_clean.size)
        lost = rng.random(t.size) < 0.02
        drift = 6.0 * t / t[-1] + 2.0 * np.sin(2 * np.pi * t / 120.0)
        for angle in REPORTED_ANGLES:
            noisy = table[angle] + rng.normal(0.0, 0.5, t.size) + drift
            noisy[lost] = np.nan
            reps = detect_repetitions(noisy * DEG, t, include=EXERCISE)
            clean = detect_repetitions(table[angle] * DEG, t_clean, include=EXERCISE)
            assert len(reps) == len(expected.get(angle, [])), f"{name} {angle}"
            if reps:
                assert [r.direction for r in reps] == [r.direction for r in clean]
                off = max(abs(a.amplitude_deg - b.amplitude_deg)
                          for a, b in zip(reps, clean, strict=True))
                late = max(abs(a.peak_s - b.peak_s) / flat_top(t_clean, table[angle], b.peak_s)
                           for a, b in zip(reps, clean, strict=True))
                worst[f"{name}/{angle}"] = (len(reps), round(off, 2), round(late, 2))
                assert off < 1.5, f"{name} {angle}: amplitude off by {off:.2f} deg"
                assert late <= 1.0, f"{name} {angle}: peak moved {late:.2f} of its flat top"
    print(f"seed {seed}: count, worst amplitude change [deg], worst peak shift [share of "
          f"the flat top]: {worst}")


def flat_top(t, values, peak_s, band_deg=0.5):
    """How long [s] ``values`` [deg] stay within ``band_deg`` of their value at ``peak_s``
    on the longer side of it, plus a sample: where a noisy copy's peak may fall."""
    i = int(np.searchsorted(t, peak_s))
    off = np.flatnonzero(np.abs(values - values[i]) > band_deg)
    before = off[off < i]
    after = off[off > i]
    first = before[-1] + 1 if before.size else 0
    last = after[0] - 1 if after.size else len(t) - 1
    return max(t[i] - t[first], t[last] - t[i]) + (t[1] - t[0])


def raised_cosines(plan, rate_hz=100.0, rest_s=2.0, rest_level_deg=0.0):
    """A series [deg] resting ``rest_s`` before, between and after repetitions given as
    ``(signed amplitude [deg], duration [s])``; returns t, angle [deg] and the peak times."""
    pieces, peaks, clock = [np.zeros(int(rest_s * rate_hz))], [], rest_s
    for amplitude, duration in plan:
        tau = np.arange(round(duration * rate_hz)) / rate_hz
        pieces.append(amplitude * (1 - np.cos(2 * np.pi * tau / duration)) / 2)
        peaks.append(clock + duration / 2)
        clock += duration + rest_s
        pieces.append(np.zeros(int(rest_s * rate_hz)))
    angle = np.concatenate(pieces) + rest_level_deg
    return np.arange(angle.size) / rate_hz, angle, np.array(peaks)


PLAN = [(30.0, 2.0), (45.0, 3.0), (-20.0, 2.5), (60.0, 4.0), (-12.0, 1.5)]


def test_synthetic_repetitions_in_closed_form():
    t, angle, peaks = raised_cosines(PLAN, rest_level_deg=7.0)
    reps = detect_repetitions(angle * DEG, t)
    assert len(reps) == len(PLAN)
    for r, (amplitude, duration), peak in zip(reps, PLAN, peaks, strict=True):
        inset = duration * np.arcsin(0.1) / (2 * np.pi)
        expected_velocity = np.pi * abs(amplitude) / duration
        print(f"{amplitude:+.0f} deg over {duration} s: amplitude {r.amplitude_deg:.3f}, "
              f"movement time {r.movement_time_s:.3f} (closed form "
              f"{duration - 2 * inset:.3f}) s, peak velocity {r.peak_velocity_deg_s:.2f} "
              f"({expected_velocity:.2f}) deg/s")
        assert r.direction == np.sign(amplitude)
        # the low-pass rings into the rest samples by far less than 1e-3°
        assert r.rest == pytest.approx(7.0 * DEG, abs=1e-3 * DEG)
        assert r.amplitude_deg == pytest.approx(abs(amplitude), abs=0.01)
        assert r.peak_angle == pytest.approx((7.0 + amplitude) * DEG, abs=0.01 * DEG)
        # times to a sample (10 ms), plus one for the low-pass's rounding of the onset
        assert abs(r.peak_s - peak) <= 0.011
        assert abs(r.start_s - (peak - duration / 2 + inset)) <= 0.021
        assert abs(r.end_s - (peak + duration / 2 - inset)) <= 0.021
        assert r.peak_velocity_deg_s == pytest.approx(expected_velocity, rel=0.01)


#: How patients make repetitions: (name, signed turns [deg, s], both ways, rest level
#: [deg], rest between [s], the repetitions a therapist counts: docs/programs.md's table).
CYCLES = [
    ("palm down then up x5", [(70.0, 2.0), (-70.0, 2.0)] * 5, True, 0.0, 1.0, 5),
    ("palm down x5, then up x5", [(70.0, 2.0)] * 5 + [(-70.0, 2.0)] * 5, True, 0.0, 1.0, 5),
    ("palm down x5, up x3", [(70.0, 2.0), (-70.0, 2.0)] * 3 + [(70.0, 2.0)] * 2, True, 0.0,
     1.0, 5),
    ("up first, then down x4", [(-60.0, 2.0), (60.0, 2.0)] * 4, True, 0.0, 1.0, 4),
    ("resting palm down, turning up and back x5", [(-130.0, 3.0)] * 5, True, 65.0, 1.0, 5),
    ("no pause at thumb up, x6", [(70.0, 1.5), (-70.0, 1.5)] * 6, True, 0.0, 0.2, 6),
    ("wrist down then up x4", [(55.0, 2.0), (-45.0, 2.0)] * 4, True, 0.0, 1.0, 4),
    ("arm out then in x3", [(50.0, 2.5), (-40.0, 2.5)] * 3, True, 0.0, 1.0, 3),
    ("elbow bent and straightened x4", [(120.0, 3.0)] * 4, False, 0.0, 1.0, 4),
]


@pytest.mark.parametrize("name,plan,both_ways,rest_deg,rest_s,truth", CYCLES,
                         ids=[c[0] for c in CYCLES])
@pytest.mark.parametrize("seed", [None, 1, 2, 3])
def test_a_repetition_is_a_full_cycle_counted_once(name, plan, both_ways, rest_deg, rest_s,
                                                   truth, seed):
    """docs/programs.md, One repetition: a full cycle out and back counted once. Noise-free
    (``seed`` None), and as a phone measures it (``seed``): 60 Hz, 2-5 ms time-stamp jitter,
    1.5° of white noise on the angle (a phone's 6-axis estimate, test_phone_kit_accuracy's
    RMSE bar is 2°) and a drift of the rest of 4° a minute."""
    rate = 100.0 if seed is None else 60.0
    t, angle, _ = raised_cosines(plan, rate_hz=rate, rest_s=rest_s, rest_level_deg=rest_deg)
    if seed is not None:
        rng = np.random.default_rng(seed)
        t = t + rng.uniform(-1, 1, t.size) * rng.uniform(0.002, 0.005) * 0.5
        angle = angle + rng.normal(0, 1.5, t.size) + 4.0 * t / 60.0
    excursions = detect_repetitions(angle * DEG, t)
    counted = count_repetitions(excursions, both_ways)
    print(f"{name} (seed {seed}): {len(excursions)} excursions "
          f"{[r.direction for r in excursions]}, {counted} repetitions (truth {truth})")
    assert len(excursions) == len(plan)
    assert counted == truth


def test_both_ways_angles_are_the_catalogues():
    """The both-ways angles are those of the catalogue's exercises that go to both sides
    of rest (turn the palm, bend the wrist, turn the arm out and in) and the wrist's side
    bend; the elbow's and the shoulder's raises go one way."""
    from armtrack.server.programs.catalogue import CATALOGUE

    assert {e.name for e in CATALOGUE.values() if e.both_ways} == {
        "pronation", "wrist_flexion", "shoulder_rotation"}
    assert BOTH_WAYS == {"forearm_pronation", "wrist_flexion", "wrist_deviation",
                         "shoulder_rotation"}


def test_still_series_has_no_repetition():
    t = np.arange(0, 60, 0.01)
    rng = np.random.default_rng(3)
    assert detect_repetitions(np.full(t.size, 0.3), t) == ()
    assert detect_repetitions((12 + rng.normal(0, 0.5, t.size)) * DEG, t) == ()
    assert detect_repetitions(np.full(t.size, np.nan), t) == ()


@pytest.mark.parametrize("tremor_hz", [3.0, 5.0])
def test_tiny_wobbles_are_not_counted(tremor_hz):
    """Excursions of 7° (under the 10° minimum) and a ±4° tremor at rest, between real
    repetitions: only the real ones count. The tremor passes the 3-Hz low-pass with the
    gain |H| of a 4th-order Butterworth; the rest level is then known to within the
    filtered tremor's amplitude, and so is the repetitions' amplitude."""
    t, angle, _ = raised_cosines([(7.0, 1.0), (40.0, 2.0), (-7.0, 1.0), (7.0, 1.5),
                                  (40.0, 2.0)])
    tremor = 4.0 * np.sin(2 * np.pi * tremor_hz * t) * (angle == 0)
    reps = detect_repetitions((angle + tremor) * DEG, t)
    filtered = 4.0 / np.sqrt(1 + (tremor_hz / 3.0) ** 8)
    print(f"tremor {tremor_hz} Hz (±{filtered:.2f}° after the low-pass): amplitudes "
          f"{np.round(signed_amplitudes(reps), 3).tolist()}")
    assert signed_amplitudes(reps) == pytest.approx([40.0, 40.0], abs=filtered)


def test_turning_back_before_rest_is_one_repetition():
    t = np.arange(0, 12, 0.01)
    # 0 → 120 → 60 → 120 → 0 between 2 s and 10 s
    knots_t, knots_a = [0, 2, 4, 6, 8, 10, 12], [0, 0, 120, 60, 120, 0, 0]
    angle = np.interp(t, knots_t, knots_a)
    reps = detect_repetitions(angle * DEG, t, params=RepetitionParams(lowpass_hz=None))
    assert len(reps) == 1 and reps[0].amplitude_deg == pytest.approx(120.0)


def test_incomplete_excursions_at_the_edges_are_not_counted():
    t, angle, peaks = raised_cosines([(50.0, 4.0)] * 3)
    cut = (t > peaks[0]) & (t < peaks[2])  # starts and ends mid-repetition
    reps = detect_repetitions(angle[cut] * DEG, t[cut])
    assert len(reps) == 1 and reps[0].peak_s == pytest.approx(peaks[1], abs=0.011)


def test_excluded_windows_and_gaps():
    """A T-pose-like hold inside an excluded window is not exercise; a long gap cuts."""
    t, angle, peaks = raised_cosines([(90.0, 6.0), (40.0, 2.0), (40.0, 2.0)])
    assert len(detect_repetitions(angle * DEG, t)) == 3
    tpose = [(peaks[0] - 3.5, peaks[0] + 3.5)]
    reps = detect_repetitions(angle * DEG, t, exclude=tpose)
    assert signed_amplitudes(reps) == pytest.approx([40.0, 40.0], abs=0.01)
    reps = detect_repetitions(angle * DEG, t, include=tpose)  # rest on both sides: counts
    assert signed_amplitudes(reps) == pytest.approx([90.0], abs=0.01)
    reps = detect_repetitions(angle * DEG, t, include=[(peaks[0] - 2.0, peaks[2] + 3.0)])
    assert signed_amplitudes(reps) == pytest.approx([40.0, 40.0], abs=0.01)
    lossy = angle.copy()
    lossy[(t > peaks[1] - 0.5) & (t < peaks[1] + 0.5)] = np.nan  # 1 s lost: longer than 0.25
    assert len(detect_repetitions(lossy * DEG, t)) == 2
    lossy = angle.copy()
    lossy[(t > peaks[1] - 0.1) & (t < peaks[1] + 0.1)] = np.nan  # 0.2 s: interpolated over
    assert len(detect_repetitions(lossy * DEG, t)) == 3


def test_strong_drift_with_rest_windows_and_with_the_tracked_mode():
    """Rest drifting 15° over 100 s (0.15°/s) under 40° repetitions."""
    t, angle, _ = raised_cosines([(40.0, 3.0)] * 16, rest_s=3.0)
    drift = 15.0 * t / t[-1]
    reps = detect_repetitions((angle + drift) * DEG, t)
    print(f"tracked mode: {len(reps)} reps, amplitudes {np.round(signed_amplitudes(reps), 2)}")
    assert signed_amplitudes(reps) == pytest.approx([40.0] * 16, abs=0.3)
    rests = [(a, a + 2.0) for a in np.arange(0.5, t[-1], 6.0)]  # inside each pause
    reps = detect_repetitions((angle + drift) * DEG, t, rest_windows=rests)
    assert signed_amplitudes(reps) == pytest.approx([40.0] * 16, abs=0.3)


def test_consistency_on_truth(truth):
    table, _, expected = truth("wrist_flexion")
    reps = detect_repetitions(table["wrist_flexion"] * DEG, table["t"], include=EXERCISE)
    both, flexion, extension = (consistency(reps), consistency(reps, 1),
                                consistency(reps, -1))
    print(f"wrist_flexion CV amplitude: both {both.amplitude_cv:.4f}, flexion "
          f"{flexion.amplitude_cv:.2e}, extension {extension.amplitude_cv:.2e}; "
          f"CV movement time {both.movement_time_cv:.2e}")
    # 60, 60, 60, 50, 50, 50 (README): sample std sqrt(6 · 25 / 5) over the mean 55
    amplitudes = np.abs(expected["wrist_flexion"])
    assert both.amplitude_cv == pytest.approx(np.std(amplitudes, ddof=1) / amplitudes.mean(),
                                              rel=1e-3)
    assert flexion.repetitions == extension.repetitions == 3
    assert flexion.amplitude_cv < 1e-3 and extension.amplitude_cv < 1e-3
    assert both.movement_time_cv < 0.01


def test_invalid_input():
    t = np.arange(0, 10, 0.01)
    with pytest.raises(InvalidShape):
        detect_repetitions(np.zeros(5), t)
    with pytest.raises(InvalidArgument):
        detect_repetitions(np.zeros(t.size), t[::-1])
    with pytest.raises(InvalidArgument):
        RepetitionParams(rest_band=12 * DEG, min_amplitude=10 * DEG)
    with pytest.raises(InvalidArgument):
        detect_repetitions(np.zeros(t.size), t, rest_windows=[(20.0, 30.0)])
    with pytest.raises(InvalidShape):
        detect_repetitions(np.zeros(t.size), t, exclude=[1.0, 2.0, 3.0])
