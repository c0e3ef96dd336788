"""Estimation on real data (issue 18): the RING arm recordings and BROAD against their bars.

Real data cannot be generated: these tests skip without ``../shared`` (a user's clone has
none). Scoring as ``../shared/data/ring/README.md`` and ``bench/ring.py`` (the same
functions): RMSE of each angle over t ≥ 5 s. Trial 1 was used for tuning, trial 2 was not.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

RING_BAR_DEG = 3.0
#: 9-axis may be worse than 6-axis by this much per angle, at most [deg].
NINE_VS_SIX_DEG = 0.2
#: Recordings that miss the bar today when estimated cold (alone), with the measured figure
#: (strict: remove when met). None: trial 2's foam wrist flexion (4.08° before, its foam
#: sensors' bias never learnt) is 1.82° since a still start takes a sensor that vibrates
#: about its fixed orientation (qcf's rest_vibration).
RING_GAPS: dict[tuple[str, str], str] = {}


@pytest.fixture(scope="module")
def ring_dir(shared_dir) -> Path:
    path = shared_dir / "data" / "ring"
    if not (path / "arm").is_dir():
        pytest.skip(f"needs the RING data ({path})")
    return path


@pytest.fixture(scope="module")
def ring_memory(ring_dir):
    """Every arm recording cold, and trial 2 with trial 1's remembered biases (ring.py)."""
    import ring
    return ring.arm_with_memory(ring_dir, (1, 2))


@pytest.fixture(scope="module")
def ring_scores(ring_memory):
    return {name: (result["cold"], result["warnings"]) for name, result in ring_memory.items()}


@pytest.mark.parametrize("trial", [1, 2])
@pytest.mark.parametrize("mounting", ["rigid", "nonrigid"])
def test_ring_arm_recordings_meet_the_bar_and_nine_axis_is_no_worse(ring_scores, trial,
                                                                     mounting):
    import ring
    base = f"ring_trial{trial}_{mounting}"
    nine, warnings = ring_scores[f"{base}_9axis"]
    six, _ = ring_scores[f"{base}_6axis"]
    print(f"{base}: 9-axis " + ", ".join(f"{a} {nine[a]:.2f}" for a in ring.ANGLES)
          + " | 6-axis " + ", ".join(f"{a} {six[a]:.2f}" for a in ring.ANGLES))
    for angle in ring.ANGLES:
        assert nine[angle] <= six[angle] + NINE_VS_SIX_DEG, (angle, nine[angle], six[angle])
    # the chain's sensors see different fields: the kit is told in plain words
    assert any("magnetic field" in w for w in warnings), warnings
    missed = {a: six[a] for a in ring.ANGLES if six[a] > RING_BAR_DEG}
    expected = {a for (b, a) in RING_GAPS if b == base}
    assert set(missed) == expected, missed


@pytest.mark.parametrize("mounting", ["rigid", "nonrigid"])
def test_ring_trial2_from_trial1s_remembered_biases_meets_the_bar(ring_memory, mounting):
    """A kit remembers each sensor's last learnt gyroscope bias: trial 2 started from what
    the same sensors (same mounting) learnt in trial 1 — never from trial 2 or the truth.
    Trial 1's foam sensors learnt theirs in its first 0.6 s, still (a provisional bias);
    trial 2's rock on the foam there (0.03–0.08 rad/s) and learn theirs cold as well since
    qcf's rest_vibration (a still start replaces the memory)."""
    import ring
    for axes in ("9axis", "6axis"):
        learnt = ring_memory[f"ring_trial1_{mounting}_{axes}"]["learnt"]
        assert set(learnt) == {"upper_arm", "forearm", "hand"}
        assert all(v.learnt in ("rest", "still start") for v in learnt.values())
    nine = ring_memory[f"ring_trial2_{mounting}_9axis"]
    six = ring_memory[f"ring_trial2_{mounting}_6axis"]
    print(f"ring_trial2_{mounting} cold → with trial 1's memory: " + ", ".join(
        f"{a} {six['cold'][a]:.2f} → 6-axis {six['memory'][a]:.2f} / 9-axis "
        f"{nine['memory'][a]:.2f}" for a in ring.ANGLES))
    for angle in ring.ANGLES:
        assert six["memory"][angle] <= RING_BAR_DEG and nine["memory"][angle] <= RING_BAR_DEG
        assert nine["memory"][angle] <= six["memory"][angle] + NINE_VS_SIX_DEG


def test_broad_meets_the_bars(shared_dir):
    """BROAD (the 30 shared trials, BROAD's own metric over the movement phase, mean of
    the per-trial RMSE): qcf 9D total ≤ 2.3°, 6D inclination ≤ 0.72°, told the kit's
    gyroscope delay behind its accelerometer as BROAD's kit would declare it
    (``docs/extensions/gyro-delay.md``): measured against the optical reference
    (``bench/timing.py``) on the *other* trials (leave one out), never on the scored one.
    Undeclared (as a kit that does not know its timing) it stays at 9D 2.40°, 6D 0.93°."""
    import broad
    import timing
    from armtrack.estimator.orientation import make_filter
    path = shared_dir / "data" / "broad"
    files = sorted(path.glob("*.mat"))
    if not files:
        pytest.skip(f"needs the BROAD subset ({path})")
    delays = timing.held_out_delays(files)
    total, inclination = [], []
    for file in files:
        trial = broad.load_trial(file, ())
        delay = delays[trial.name]
        q9 = make_filter("qcf", gyro_delay_s=delay).update_batch(
            trial.t, trial.acc, trial.gyr, trial.mag).q
        q6 = make_filter("qcf", gyro_delay_s=delay).update_batch(
            trial.t, trial.acc, trial.gyr, None).q
        total.append(broad.broad_errors(q9, trial.opt_quat, trial.movement)[0])
        inclination.append(broad.broad_errors(q6, trial.opt_quat, trial.movement)[2])
    print(f"BROAD {len(files)} trials, declared gyroscope delay (held out) "
          f"{min(delays.values()) * 1e3:.3f}–{max(delays.values()) * 1e3:.3f} ms: "
          f"9D {np.mean(total):.3f}°, 6D inclination {np.mean(inclination):.3f}°")
    assert np.mean(total) <= 2.3
    assert np.mean(inclination) <= 0.72


#: Why RING's 9D seg4–seg5 pair is above VQF's (strict: remove when met). Measured with
#: ``ring.sensor_headings`` (bench/README.md, ring.py): the field bends along the chain.
RING_9D_SEG45 = (
    "measured 9D seg4–seg5 23.56° (VQF 16.69°) on trial 1 and 22.49° (VQF 19.47°) on trial 2 "
    "(held out); the other four rigid hinge pairs are below VQF. The field read with the "
    "optical truth points +34/+37° off the chain's north at seg5 and +8/+11° at seg4, in both "
    "trials (−32…+37° from seg1 to seg5; a hard-iron fit turns seg5's field by under 2°, a "
    "soft- and hard-iron fit leaves 3.4–5.7 µT: a bent field, not a calibration a filter could "
    "learn). qcf follows each sensor's field (seg4 −1.0/+0.5°, seg5 +20.8/+20.8° about its "
    "north); VQF scores lower because it starts seg4 at the mean of its first 9 s (the "
    "disturbed start included: k ≥ 1/N for tauMag), then integrates its gyroscope alone until "
    "it first accepts seg4's field at 40.6/22.2 s (+13.8/+16.9°), erring the way seg5's field "
    "bends. Per sensor qcf's heading is the closer on all ten: "
    "test_ring_nine_axis_heading_per_sensor_is_closer_than_vqfs")


@pytest.fixture(scope="module")
def ring_joints(ring_dir):
    """Per joint (ring.py): armtrack's filter and VQF, one sensor at a time, rigid IMUs."""
    pytest.importorskip("vqf")
    import ring
    return {trial: ring.score_chain(ring.load_chain(ring_dir, trial, "rigid"), ring.FILTERS)
            for trial in (1, 2)}


def _hinge_rows(rows, mode):
    return {(r["item"], r["filter"]): r for r in rows if r["hinge"] and r["mode"] == mode}


@pytest.mark.parametrize("trial", [1, 2])
def test_ring_joints_six_axis_below_vqf_with_less_drift(ring_joints, trial):
    """RING per joint, 6D (issue 18): below VQF on every rigid hinge pair, in RMSE and in
    heading drift (trial 1 tuned on, trial 2 held out)."""
    rows = _hinge_rows(ring_joints[trial], "6D")
    for item in sorted({item for item, _ in rows}):
        ours, vqf = rows[(item, "armtrack")], rows[(item, "vqf")]
        print(f"{item} 6D: armtrack {ours['rmse']:.2f}° ({ours['drift']:.1f} °/min), "
              f"VQF {vqf['rmse']:.2f}° ({vqf['drift']:.1f} °/min)")
        assert ours["rmse"] < vqf["rmse"]
        assert abs(ours["drift"]) < abs(vqf["drift"])


@pytest.mark.parametrize("trial", [
    pytest.param(1, marks=pytest.mark.xfail(strict=True, reason=RING_9D_SEG45)),
    pytest.param(2, marks=pytest.mark.xfail(strict=True, reason=RING_9D_SEG45))])
def test_ring_joints_nine_axis_below_vqf(ring_joints, trial):
    """RING per joint, 9D (issue 18): below VQF on every rigid hinge pair."""
    rows = _hinge_rows(ring_joints[trial], "9D")
    items = sorted({item for item, _ in rows})
    for item in items:
        print(f"{item} 9D: armtrack {rows[(item, 'armtrack')]['rmse']:.2f}°, "
              f"VQF {rows[(item, 'vqf')]['rmse']:.2f}°")
    above = [item for item in items if rows[(item, "armtrack")]["rmse"]
             >= rows[(item, "vqf")]["rmse"]]
    assert not above, above


@pytest.mark.parametrize("trial", [1, 2])
def test_ring_nine_axis_heading_per_sensor_is_closer_than_vqfs(ring_dir, trial):
    """Each rigid sensor's 9D heading against the optical truth, about each filter's own
    north (the world's north is arbitrary): armtrack's RMS below VQF's on every sensor,
    t ≥ 5 s. The per-joint score rewards two sensors erring alike; this one does not."""
    pytest.importorskip("vqf")
    import ring
    for r in ring.sensor_headings(ring.load_chain(ring_dir, trial, "rigid")):
        print(f"{r['item']}: field {r['field_heading']:+.1f}° off the chain's north; heading "
              f"error RMS armtrack {r['armtrack_rms']:.1f}°, VQF {r['vqf_rms']:.1f}°")
        assert r["armtrack_rms"] < r["vqf_rms"], r
