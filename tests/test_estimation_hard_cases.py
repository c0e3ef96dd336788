"""The simulator's harder cases (issue 18), several seeds and bodies each, against the
accuracy bar of issue 4 (every angle 1°, 6-axis 2°; wrist 1 cm): a field disturbed
differently per sensor from the first sample; packed samples with equal stamps; a trunk
swaying several degrees slowly, with jitter; long sessions with a drifting gyroscope bias
(6-axis with rests, and 9-axis without: there the magnetometer must help)."""

import functools
from dataclasses import replace

import numpy as np
import pytest
from armtrack.estimator.pipeline import estimate_recording
from armtrack.estimator.simulation import ImuErrors, SimulationConfig, exercise_motion, simulate
from armtrack.estimator.simulation.profiles import Profile, Sine
from test_pipeline import ANGLE_BAR_DEG, WRIST_BAR_CM, score, sim_truth_deg

EXERCISES = ("elbow_flexion", "drinking", "reach", "pronation")


def body(seed: int) -> float:
    """A body height [m] per seed, 1.55–1.95 m."""
    return float(np.random.default_rng(1000 + seed).uniform(1.55, 1.95))


def run(config: SimulationConfig):
    sim = simulate(config)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions)
    return worst, worst_deg, wrist_cm, calibration


def drifting(seed: int) -> ImuErrors:
    """Noise as the shared recordings, and a bias random walk of 2–3·10⁻⁴ rad/s/√s."""
    walk = float(np.random.default_rng(2000 + seed).uniform(2e-4, 3e-4))
    return ImuErrors(gyro_noise=0.004, acc_noise=0.04, mag_noise=0.4, gyro_bias_walk=walk)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_field_disturbed_per_sensor_from_the_first_sample(seed):
    """Each sensor starts beside its own magnet (20–50 µT at the sensor, for 20–30 s,
    calibration included): the kit's magnetometers are left out, said in plain words."""
    config = SimulationConfig(exercise=EXERCISES[seed % 4], seed=seed, height_m=body(seed),
                              start_disturbance_s=(20.0, 30.0))
    worst, worst_deg, wrist_cm, calibration = run(config)
    print(f"disturbed from t=0, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert [w.code for w in calibration.warnings] == ["magnetic-field-disturbed"]
    assert "magnetic field" in calibration.warnings[0].message
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


@pytest.mark.parametrize("seed, pack", [(1, 4), (2, 2), (3, 4)])
def test_packed_samples_with_equal_stamps(seed, pack):
    config = SimulationConfig(exercise=EXERCISES[seed % 4], seed=seed, height_m=body(seed),
                              pack_size=pack)
    worst, worst_deg, wrist_cm, _ = run(config)
    print(f"packs of {pack}, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


#: What the sway does: the thorax's upright, taken as the trunk's mean over the poses
#: (0.5–8 s), keeps up to ~2° of a 0.1–0.2 Hz sway's lean, which the two-direction arm
#: calibration turns into a rotation about the vertical (pronation, abduction 1.07–1.78°
#: on seeds 1, 3, 4, 5, 7, 8 before). The calibration now takes the part of that lean
#: toward the thorax's X out: the upright is square to the axis about which the arm turned
#: between the poses relative to the trunk sensor (a sway turns both alike), weighed
#: against the mean by the trunk's tilt range (a still trunk keeps the mean): seeds 1–5
#: 1.63/0.96/1.51/1.47/1.07° → 0.77/0.88/0.66/0.60/0.48°; scratch seeds 6–8
#: 0.56/1.78/1.57° → 0.69/0.90/0.49°. The upright is now the sway's centre, not its mean
#: (``calibrate._sway_centre``: the sway's partial cycles cancelled as far as the poses'
#: span allows; ``test_the_thorax_upright_through_a_random_sway``): this sine sway's
#: seeds 1–5 0.57/0.56/0.61/0.68/0.54° → 0.66/0.49/0.70/0.85/0.66° (its side lean's
#: plain mean was small already), the random sway's better (bench/README.md). No sensor
#: ever rests (the arm sways with the trunk), so every bias is learnt in motion.
def sway_config(seed: int) -> SimulationConfig:
    rng = np.random.default_rng(3000 + seed)
    return SimulationConfig(exercise="reach", seed=seed, height_m=body(seed),
                            rate_hz=(50.0, 60.0)[seed % 2],
                            sensors=("trunk", "upper_arm", "forearm", "hand"),
                            trunk_sway=(float(rng.uniform(6, 10)), float(rng.uniform(0.1, 0.2))),
                            jitter_s=float(rng.uniform(0.001, 0.003)))


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_trunk_sway_slow_and_large_with_jitter(seed):
    config = sway_config(seed)
    worst, worst_deg, wrist_cm, _ = run(config)
    print(f"trunk sway {config.trunk_sway}, seed {seed}: {worst} {worst_deg:.2f}°, "
          f"wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


#: The same swaying kit without a magnetometer. Its calibration is the 9-axis one (the
#: thorax's upright, not gravity, for the arm; square to the abduction axis) once a first
#: pass has put the filters in one world, and the trunk sensor's turn about its long axis,
#: which the N-pose cannot tell from its filter's own heading, comes from the held poses'
#: sway: arm and trunk turn as one, so their gyroscopes give the turn between the two
#: filters' worlds. Without gyroscope bias, worst angle before: seeds 1–3 6.92/2.62/4.57°
#: (every segment tilted by the sway's mean, the trunk turned 1.5/11.8/20.5° about its long
#: axis). With the case's biases the trunk's heading drifted 10–20° from the upper arm's
#: (13.15/3.25/11.57° before): a trunk that only sways never shows its bias about the
#: vertical to the tilt (10 mrad/s on seeds 1 and 3, never learnt); the same held poses
#: give it (``biases_from_poses``: ``ω_trunk − R_trunk_arm ω_arm`` is the two biases'
#: difference, and the arm's turn between the poses tells them apart), and the trunk's
#: filter starts from it; the arm's sensors, which never rest either, start from theirs.
def six_axis_sway(seed: int, gyro_bias_max: float) -> SimulationConfig:
    return replace(sway_config(seed), nine_axis=False, gyro_bias_max=gyro_bias_max)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_six_axis_trunk_sway_without_gyroscope_bias(seed):
    worst, worst_deg, wrist_cm, _ = run(six_axis_sway(seed, 0.0))
    print(f"6-axis trunk sway, no bias, seed {seed}: {worst} {worst_deg:.2f}°, "
          f"wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


def six_axis_sway_kit(kind: str, seed: int, config: SimulationConfig | None = None):
    """The 6-axis swaying kit of ``seed`` (``config``: that kit changed) under the ``sine``
    sway of its config, ``random_sway`` or ``irregular_sway``, from the first sample."""
    if config is None:
        config = six_axis_sway(seed, sway_config(seed).gyro_bias_max)
    if kind == "sine":
        return simulate(config)
    trunk = random_sway(seed, config.trunk_sway[0]) if kind == "random" else \
        irregular_sway(seed, *config.trunk_sway)
    return simulate(replace(config, trunk_sway=None), motion=replace(
        exercise_motion(config.exercise, calibration=True, npose_s=config.npose_s), trunk=trunk))


def pose_biases(recording):
    """``biases_from_poses`` on every sample of ``recording`` (qcf tracks)."""
    from armtrack.estimator.calibration import CalibrationPlan
    from armtrack.estimator.pipeline.calibrate import biases_from_poses
    from armtrack.estimator.pipeline.tracks import SensorTrack

    tracks = {}
    for name, stream in recording.sensors.items():
        tracks[name] = SensorTrack(name, "qcf")
        tracks[name].append(stream.t, stream.acc, stream.gyr, None)
    return biases_from_poses(tracks, CalibrationPlan.from_poses(list(recording.calibration)))


def test_the_held_poses_show_every_sensors_gyroscope_bias():
    """A 6-axis swaying kit's N- and T-pose (``biases_from_poses``): the trunk's bias
    about the vertical within 1 mrad/s, and each arm sensor's whole bias to within half of
    it (measured 3–36 % here; a filter that starts from zero is 100 % off): the rigid
    fits' ``ω_trunk − C ω_arm`` with gravity in ``C``, and each sensor's own tilt drift
    over each pose for the part along the arm's turn between the poses, which the fits
    cannot tell from the trunk's (without the tilt drift that part was 14–20 mrad/s off on
    the sine sway's seeds 2 and 3). Before, only the trunk's vertical part was found."""
    from scipy.spatial.transform import Rotation

    for kind, seed in (("sine", 3), ("random", 6), ("irregular", 2)):
        sim = six_axis_sway_kit(kind, seed)
        recording = sim.recording
        found = pose_biases(recording)
        assert found is not None
        errors = []
        for name, stream in recording.sensors.items():
            R = sim.truth.R_world_sensor[name]
            rate = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:])).as_rotvec() \
                / np.diff(stream.t)[:, None]
            true = np.median(0.5 * (stream.gyr[:-1] + stream.gyr[1:]) - rate, axis=0)
            if name == "trunk":
                off = abs(found.vertical - true @ found.up)
                errors.append(f"trunk vertical {off * 1e3:.2f} mrad/s")
                assert off <= 1e-3
            else:
                off = np.linalg.norm(found.arm[name][0] - true)
                errors.append(f"{name} {off * 1e3:.2f} of {np.linalg.norm(true) * 1e3:.2f}")
                assert off <= 0.5 * np.linalg.norm(true)
        print(f"{kind} sway seed {seed}: " + ", ".join(errors))


#: The consistency test's kits: the 6-axis sway tests' seeds (one per seed: a seed's sine,
#: random and irregular kits draw the same noise) and 20 seeds no test scores.
POSE_BIAS_CASES = (("sine", 1), ("sine", 2), ("sine", 3), ("random", 6), ("random", 10),
                   ("irregular", 4), ("irregular", 5),
                   *(("sine", s) for s in range(21, 27)), *(("random", s) for s in range(27, 34)),
                   *(("irregular", s) for s in range(34, 41)))


def test_the_held_poses_biases_are_as_sure_as_they_say():
    """Each bias the held poses give is off by about what its covariance says: over the
    cases, the squared errors normalised by it (the trunk's about the vertical, 1 degree of
    freedom; each arm sensor's whole, 3) sum to within the chi-square distribution's
    0.5–99.5 % range. Before (issue 18): means trunk 46.1, arm 41.7–44.7 (errors 2.30 and
    2.45–2.53 mrad/s RMS against σ 0.36 and 0.65–0.68): the sway's acceleration, slow and
    alike for seconds, taken for white noise in the tilt drifts; rigid fits stuck in a
    wrong turn; a gyroscope's noise over a pose counted once per fit. Now 1.70, 2.86–3.44
    (errors 0.57 and 0.79–0.86 against σ 0.42 and 0.81–0.82). The truth is exact: the same
    draws without noise, with and without the bias."""
    from scipy.stats import chi2

    sums = {"trunk": 0.0, "upper_arm": 0.0, "forearm": 0.0, "hand": 0.0}
    for kind, seed in POSE_BIAS_CASES:
        config = six_axis_sway(seed, sway_config(seed).gyro_bias_max)
        quiet = replace(config, errors=replace(config.errors, gyro_noise=0.0))
        biased = six_axis_sway_kit(kind, seed, quiet).recording.sensors
        unbiased = six_axis_sway_kit(kind, seed, replace(quiet, gyro_bias_max=0.0)
                                     ).recording.sensors
        true = {s: np.median(biased[s].gyr - unbiased[s].gyr, axis=0) for s in biased}
        found = pose_biases(six_axis_sway_kit(kind, seed, config).recording)
        sums["trunk"] += ((found.vertical - true["trunk"] @ found.up) / found.sigma) ** 2
        for sensor, (bias, covariance) in found.arm.items():
            off = bias - true[sensor]
            sums[sensor] += float(off @ np.linalg.solve(covariance, off))
    n = len(POSE_BIAS_CASES)
    for sensor, total in sums.items():
        dof = n * (1 if sensor == "trunk" else 3)
        low, high = chi2.ppf(0.005, dof), chi2.ppf(0.995, dof)
        print(f"{sensor}: normalised squared error mean {total / n:.2f} "
              f"({total:.1f} of {low:.1f}–{high:.1f} over {n} kits)")
        assert low <= total <= high, sensor


@pytest.mark.parametrize("nine_axis", [False, True])
def test_a_noiseless_still_kit_has_finite_pose_biases(nine_axis):
    """The held poses of a still kit whose readings carry no noise (a simulation's, or a
    gyroscope whose resolution hides its noise): every variance the pose-bias fit
    (``biases_from_poses``) takes from the readings is zero there. Before, floored at
    1e-30, its information held 1e30 beside 1e4: the trunk's σ came out NaN (the square
    root of a negative variance) and the estimation stopped with LinAlgError ('Eigenvalues
    did not converge') restarting the trunk's filter. Now σ finite and positive, the arm's
    covariances positive definite, and the estimates within the bars."""
    config = replace(sway_config(3), trunk_sway=None, nine_axis=nine_axis)
    config = replace(config, errors=replace(config.errors, gyro_noise=0.0, acc_noise=0.0,
                                            mag_noise=0.0))
    sim = simulate(config)
    found = pose_biases(sim.recording)
    assert found is not None
    eigen = {s: np.linalg.eigvalsh(c) for s, (_, c) in found.arm.items()}
    print(f"noiseless still kit (nine_axis {nine_axis}): trunk σ {found.sigma * 1e3:.4f} "
          "mrad/s, arm covariances' eigenvalues "
          + ", ".join(f"{s} {e.min():.2e}–{e.max():.2e}" for s, e in eigen.items()))
    assert np.isfinite(found.sigma) and found.sigma > 0
    assert all(np.all(np.isfinite(e)) and e.min() > 0 for e in eigen.values())
    worst, worst_deg, wrist_cm, _ = run(config)
    print(f"  {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[nine_axis] and wrist_cm <= WRIST_BAR_CM


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_six_axis_trunk_sway(seed):
    """With the case's gyroscope biases (up to 12 mrad/s an axis): seed 1 13.15° →
    1.93° (wrist 11.58 → 0.80 cm); seed 3 11.57° → 2.03° → 1.33° (wrist 0.98 cm) once the
    elbow follows its sensors' heading drift (``constraints``: the forearm's heading ran
    off the upper arm's at 0.2°/s, which the mean over 20 s lagged by 2–4°). Then, every
    sensor's filter restarted from the biases the held poses show (``biases_from_poses``:
    no sensor of a swaying kit ever rests, and the arm's tilt windows learnt theirs only
    slowly, 3–10 mrad/s off through most of the exercise), seeds 1/2/3 1.93/2.00/1.33° →
    0.58/0.59/1.02° (wrist 0.80/1.11/0.98 → 0.53/0.52/0.96 cm)."""
    worst, worst_deg, wrist_cm, _ = run(six_axis_sway(seed, sway_config(seed).gyro_bias_max))
    print(f"6-axis trunk sway, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_still_trunk_keeps_its_mean_upright(seed, monkeypatch):
    """The sway's correction of the thorax's upright is weighed by how far the trunk
    leaned: on the same kit with a still trunk every sensor-to-segment rotation is the one
    the mean upright gives (the correction off), to 0.02°."""
    from armtrack.estimator.pipeline import calibrate as calibrate_module
    from scipy.spatial.transform import Rotation

    recording = simulate(replace(sway_config(seed), trunk_sway=None)).recording
    _, corrected = estimate_recording(recording)
    monkeypatch.setattr(calibrate_module, "AXIS_SIGMA_RAD", {True: np.inf, False: np.inf})
    _, mean_only = estimate_recording(recording)
    differences = {s: float(np.rad2deg(Rotation.from_matrix(
        corrected.R_sensor_segment[s] @ mean_only.R_sensor_segment[s].T).magnitude()))
        for s in corrected.R_sensor_segment}
    print(f"still trunk, seed {seed}: " + ", ".join(f"{s} {d:.4f}°"
                                                   for s, d in differences.items()))
    assert max(differences.values()) < 0.02


def calibration_only(recording, until_s: float = 9.0):
    """The calibration ``estimate_recording`` makes of ``recording`` cut at ``until_s``
    (after the T-pose's end, when calibration is final): the same one, in a second."""
    def cut(stream):
        kept = stream.t <= until_s
        return replace(stream, t=stream.t[kept], acc=stream.acc[kept], gyr=stream.gyr[kept],
                       mag=None if stream.mag is None else stream.mag[kept])
    return estimate_recording(replace(recording, points={}, sensors={
        name: cut(stream) for name, stream in recording.sensors.items()}))[1]


def test_the_thorax_upright_through_a_random_sway():
    """The 9-axis kit under the low-pass random sway, seeds 1–10: the thorax's upright the
    calibration takes (its Y in the trunk sensor's frame; every segment's calibration
    carries its error alike) against the simulator's mounting. The trunk's lean over the
    poses is known only in its changes; its plain mean kept what the sway's slow partial
    cycles left: RMS 1.02°, worst 2.23° (seed 9; the axis correction takes out the
    forward part only). Bars: RMS 0.9°, worst 1.8°. With the true upright the same
    calibration gives RMS 0.46°, worst 0.74° (the arm's own two-pose errors): the floor."""
    errors = []
    for seed in range(1, 11):
        config = sway_config(seed)
        motion = replace(exercise_motion(config.exercise, calibration=True),
                         trunk=random_sway(seed, config.trunk_sway[0]))
        sim = simulate(replace(config, trunk_sway=None), motion=motion)
        calibration = calibration_only(sim.recording)
        found = calibration.R_sensor_segment["trunk"][:, 1]
        true = sim.truth.mounts["trunk"].R_segment_sensor[1]  # the thorax's Y, sensor frame
        errors.append(float(np.rad2deg(np.arccos(np.clip(found @ true, -1.0, 1.0)))))
    rms = float(np.sqrt(np.mean(np.square(errors))))
    print("upright error per seed: " + " ".join(f"{e:.2f}" for e in errors)
          + f"°; RMS {rms:.2f}°, worst {max(errors):.2f}°")
    assert rms <= 0.9 and max(errors) <= 1.8


def test_a_long_pose_span_keeps_the_upright_fit_small(monkeypatch):
    """The upright's fit (``calibrate._sway_centre``) solves one system over the poses'
    span in blocks; the span is the kit's marks (a pose is as long as it was held), so its
    size is bounded however long they are: a 3-minute span at 50 Hz (a sine sway of 8° at
    0.15 Hz about an upright tilted 5°) is fitted over at most 240 blocks (before: 720, the
    work growing as the span's cube), and still finds that upright to 0.1°."""
    from armtrack.estimator.pipeline import calibrate as calibrate_module

    sizes = []
    solve = np.linalg.solve

    def spy(a, b):
        sizes.append(len(a))
        return solve(a, b)

    monkeypatch.setattr(calibrate_module.np.linalg, "solve", spy)
    t = np.arange(0.0, 180.0, 0.02)
    lean = np.deg2rad(5.0) + np.deg2rad(8.0) * np.sin(2 * np.pi * 0.15 * t)
    up = np.stack([np.sin(lean), np.cos(lean), np.zeros_like(t)], axis=1)
    centre, _ = calibrate_module._sway_centre(t, up)
    error = abs(np.rad2deg(np.arctan2(centre[0], centre[1])) - 5.0)
    print(f"3-min span: {sizes} blocks, upright off by {error:.3f}°")
    assert sizes and max(sizes) <= 240 and error < 0.1


def random_sway_kit(seed: int, config: SimulationConfig | None = None):
    """The kit of ``config`` (default ``sway_config(seed)``) under ``random_sway(seed)``."""
    config = sway_config(seed) if config is None else config
    motion = replace(exercise_motion(config.exercise, calibration=True, npose_s=config.npose_s),
                     trunk=random_sway(seed, config.trunk_sway[0]))
    return simulate(replace(config, trunk_sway=None), motion=motion)


def test_a_swaying_kit_is_told_its_upright_is_not_known():
    """The 9-axis kit of random sway seed 9 (its thorax's upright 1.68° off, nearly all a
    side lean the sway kept over the poses' 7.5 s): the calibration says so, in words a
    therapist can act on ('trunk-swayed', the lean's 95 % range, what to do: a still
    trunk, or a 15-s N-pose, ``test_a_longer_npose_brings_a_swaying_kit_within_the_bars``
    and ``test_a_longer_npose_on_a_nine_axis_swaying_kit``). The same kit with a
    still trunk says nothing of it. The level (2σ over the 1° bar, 2° without a
    magnetometer: ``quality.LEAN_SD_MAX_DEG``) was set from the bars before looking at
    which kits miss them. Before: no such warning. The figure names the lean (est13: 'its
    side lean is known only to ±2.5°', was 'its upright … (side lean)') and the hold the
    live view guides (``test_a_guided_npose_pins_the_trunk``)."""
    swaying = calibration_only(random_sway_kit(9).recording)
    still = calibration_only(simulate(replace(sway_config(9), trunk_sway=None)).recording)
    for name, calibration in (("swaying", swaying), ("still", still)):
        print(f"{name}: " + "; ".join(f"{w.code}: {w.message}" for w in calibration.warnings))
    found = [w for w in swaying.warnings if w.code == "trunk-swayed"]
    assert len(found) == 1 and found[0].sensor == "trunk"
    print(f"lean σ side/forward: swaying {swaying.lean_sd_deg[0]:.2f}/"
          f"{swaying.lean_sd_deg[1]:.2f}°, still {still.lean_sd_deg[0]:.3f}/"
          f"{still.lean_sd_deg[1]:.3f}°")
    assert f"side lean is known only to ±{2 * swaying.lean_sd_deg[0]:.1f}°" in found[0].message
    assert "trunk swayed" in found[0].message and "back supported" in found[0].message
    assert "N-pose) for 15–20 s, until the live view says the trunk is steady" in \
        found[0].message
    assert "trunk-swayed" not in {w.code for w in still.warnings}
    assert max(still.lean_sd_deg) < 0.5 and swaying.lean_sd_deg[0] > 0.5


def swaying_kit(kind: str, seed: int, nine_axis: bool, npose_s: float = 3.0):
    """The swaying kit of ``seed`` (9-axis ``sway_config``, else its 6-axis one with the
    case's biases) under the ``sine``, ``random`` or ``irregular`` sway, its N-pose held
    ``npose_s`` [s]."""
    config = sway_config(seed) if nine_axis else six_axis_sway(
        seed, sway_config(seed).gyro_bias_max)
    return six_axis_sway_kit(kind, seed, replace(config, npose_s=npose_s))


#: A 15-s N-pose (the poses' span 0.5–20 s, not 0.5–8) on the 6-axis kits that miss the
#: bar with the shared timeline's 3 s: tuning random 9 (1.47°, 1.06 cm) and sine 4 (2.07°,
#: 1.47 cm); held out random 11/15/18 (1.60°/1.48°/1.77°, 1.19/1.39/1.13 cm), irregular
#: 17/18 (1.30°/1.31°, 1.66/1.18 cm), sine 17/18 (0.97°/1.03°, 1.14/1.16 cm). Measured over
#: 6-axis random, irregular and sine seeds 1–20: within both bars 28 → 30 of 30 tuning, 18
#: → 28 of 30 held out (random 13 then missed at 7.20°, elbow flexion: a slow turn taken
#: for stillness, ``test_a_slow_turn_at_the_start_is_not_stillness_the_poses_contradict``,
#: now 29 of 30; random 19 missed at 1.33 cm, shoulder flexion 1.26°, until the trunk's
#: filter restarted from its whole pose bias: 0.39 cm, 0.60°; 30 of 30). A longer pose
#: draws other noise and biases (the simulator's draws follow the recording's length): the
#: same sway and body, not the same samples.
@pytest.mark.parametrize("kind, seed", [
    ("random", 9), ("sine", 4),
    ("random", 11), ("random", 15), ("random", 18), ("irregular", 17), ("irregular", 18),
    ("sine", 17), ("sine", 18), ("random", 19)])
def test_a_longer_npose_brings_a_swaying_kit_within_the_bars(kind, seed):
    """The remedy the trunk-swayed warning offers works on a 6-axis kit: the same swaying
    kit with its N-pose held 15 s meets the bars (2°, 1 cm) and its calibration no longer
    warns (the side lean's σ 0.06–0.14°, against 0.3–1.2° from 7.5 s)."""
    from armtrack.estimator.simulation.scenarios import SCORED_FROM_S, calibration_offset

    sim = swaying_kit(kind, seed, False, npose_s=15.0)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions,
                                       scored_from=SCORED_FROM_S + calibration_offset(15.0))
    print(f"6-axis {kind} sway, seed {seed}, 15-s N-pose: {worst} {worst_deg:.2f}°, wrist "
          f"{wrist_cm:.2f} cm; lean σ {calibration.lean_sd_deg[0]:.2f}/"
          f"{calibration.lean_sd_deg[1]:.2f}°; {sorted({w.code for w in calibration.warnings})}")
    assert "trunk-swayed" not in {w.code for w in calibration.warnings}
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


def test_a_slow_turn_at_the_start_is_not_stillness_the_poses_contradict():
    """The 6-axis random sway seed 13 kit with a 15-s N-pose: its upper arm turned at 0.04
    rad/s through its first half second, which qcf's still start (a provisional bias from
    a stillness from the first sample, its turn test under the accelerometer's noise over
    0.44 s) took for stillness, 42 mrad/s off; the pipeline kept that filter, as taught
    by stillness, instead of restarting it from the held poses' bias (0.5 mrad/s off,
    ``biases_from_poses``), and its tilt ran 7–11° off: elbow flexion 7.20°, wrist 6.58
    cm. A stillness whose bias the poses contradict beyond chance (both covariances) was
    a slow turn: the filter restarts from the poses' bias. Each arm filter's bias at the
    poses' end is then near the truth, and the kit within the bars (2°, 1 cm)."""
    from armtrack.estimator.pipeline import run_recording
    from armtrack.estimator.simulation.scenarios import SCORED_FROM_S, calibration_offset
    from scipy.spatial.transform import Rotation

    sim = swaying_kit("random", 13, False, npose_s=15.0)
    pipeline = run_recording(sim.recording)
    final_time = pipeline._plan().final_time(0.0)
    estimates = pipeline.finish()
    offs = {}
    for name, stream in sim.recording.sensors.items():
        R = sim.truth.R_world_sensor[name]
        rate = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:])).as_rotvec() \
            / np.diff(stream.t)[:, None]
        true = np.median(0.5 * (stream.gyr[:-1] + stream.gyr[1:]) - rate, axis=0)
        n = int(np.searchsorted(stream.t, final_time, "right"))
        fresh = pipeline._tracks[name]._new_filter()  # the filter as restarted, or not
        bias = fresh.update(stream.t[:n], stream.acc[:n], stream.gyr[:n], None).gyr_bias[-1]
        offs[name] = float(np.linalg.norm(bias - true))
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions,
                                       scored_from=SCORED_FROM_S + calibration_offset(15.0))
    print("bias off at the poses' end: " + ", ".join(f"{s} {v * 1e3:.1f}"
                                                     for s, v in offs.items())
          + f" mrad/s; {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert max(offs.values()) < 3e-3
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


#: The 9-axis swaying kits with a 15-s N-pose that missed the bar while the arm sensors
#: kept their own filters (worst angle, wrist): tuning random 9 1.38°, 0.58 cm, sine 1
#: 1.84°, 1.49 cm; held out random 11/15/20 1.11°/2.47°/1.55° (0.63/1.60/1.39 cm),
#: irregular 11 1.48°, sine 10/15 2.09°/2.24°. Random 1 missed at 1.01° (shoulder
#: rotation), 0.67 cm while the trunk's filter restarted from the poses' vertical bias
#: alone: its horizontal bias (11.9 mrad/s) was learnt again through the N-pose, whose
#: trunk orientation the thorax's calibration takes (side lean −0.31° from the sway's
#: centre, −0.55° as calibrated). Held-out irregular 14 missed at 1.24° (forearm pronation;
#: 1.21° with every true sensor-to-segment rotation): the forearm's and hand's filters,
#: restarted from the poses' biases (known to 0.2–0.4 mrad/s), took the arm hanging through
#: a slow stretch of the sway at 10–13 s (16 mrad/s) for a rest and learnt its rate as
#: their bias (tilt 2.4°, heading 2.8° off by 21 s); qcf now lets a rate through as a rest
#: only within as many σ of a bias known that well as its loose limit allows an unknown
#: one: 0.29°.
@pytest.mark.parametrize("kind, seed", [
    ("random", 1), ("random", 9), ("sine", 1),
    ("random", 11), ("random", 15), ("random", 20), ("irregular", 11), ("sine", 10),
    ("irregular", 14),
    ("sine", 15)])
def test_a_longer_npose_on_a_nine_axis_swaying_kit(kind, seed):
    """The remedy on the 9-axis kit: with a 15-s N-pose the side lean is known (σ
    0.06–0.14°), and the thorax's turn about its long axis, which comes from the arm's
    heading over the N-pose, is right once the arm's filters, like the trunk's, restart
    from the biases the held poses show (``biases_from_poses``). Before, the upper arm's
    filter kept its own: its heading windows took the long sway for a vertical bias
    (random 15: heading −1.1° off at 2 s, −4.1° at 14 s, the trunk's within ±0.6°; thorax
    turn −2.5° off). Random / irregular / sine seeds 1–20 within the 1° bar: 11 / 14 / 15
    of 20 → 19 / 19 / 20 (13 / 20 / 18 with the 3-s N-pose before, 14 / 20 / 20 now)."""
    from armtrack.estimator.simulation.scenarios import SCORED_FROM_S, calibration_offset

    sim = swaying_kit(kind, seed, True, npose_s=15.0)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions,
                                       scored_from=SCORED_FROM_S + calibration_offset(15.0))
    print(f"9-axis {kind} sway, seed {seed}, 15-s N-pose: {worst} {worst_deg:.2f}°, wrist "
          f"{wrist_cm:.2f} cm; {sorted({w.code for w in calibration.warnings})}")
    assert "trunk-swayed" not in {w.code for w in calibration.warnings}
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


def upright_errors(sim, monkeypatch) -> tuple[float, float, float, float]:
    """The calibration of ``sim``'s recording: its thorax's side lean (the sway's centre,
    before anything else turns it) and forward lean (as calibrated) against the simulator's
    mounting, and the σ it gives each [deg]."""
    from armtrack.estimator.pipeline import calibrate as calibrate_module
    from scipy.spatial.transform import Rotation

    centres = []
    fit = calibrate_module._sway_centre

    def spy(t, up):
        found = fit(t, up)
        centres.append(found[0])
        return found

    monkeypatch.setattr(calibrate_module, "_sway_centre", spy)
    calibration = calibration_only(sim.recording)
    true = sim.truth.mounts["trunk"].R_segment_sensor  # rows: the thorax's axes, sensor frame
    side = float(np.rad2deg((centres[-1] - true[1]) @ true[2]))  # up along Z: about X
    turn = Rotation.from_matrix(true @ calibration.R_sensor_segment["trunk"]).as_rotvec()
    return side, float(np.rad2deg(turn[2])), *calibration.lean_sd_deg


@pytest.mark.parametrize("seeds", [range(1, 11), range(11, 21)], ids=["tuning", "held-out"])
def test_the_uprights_lean_is_as_sure_as_it_says(seeds, monkeypatch):
    """The thorax's side and forward lean a 9-axis swaying kit's calibration takes are off
    by about the σ it gives (``Calibration.lean_sd_deg``): over the random, irregular and
    sine sway of seeds 1–10 (tuning) and 11–20 (held out), the squared errors over the
    variances sum to within the chi-square distribution's 0.5–99.5 % range (30 kits, 1
    degree of freedom each). The side lean's σ is the sway centre's under the model that
    makes it (a flat band, its size from the blocks' scatter); the forward lean's that
    centre's share and the abduction axis's (``AXIS_SIGMA_RAD``). Measured (mean per kit,
    tuning / held out; sums 22.0 / 41.1 side, 29.9 / 17.0 forward, of 13.8–53.7): side
    random 1.12 / 3.26, irregular 0.64 / 0.62, sine 0.44 / 0.24; forward 1.42 / 0.96,
    0.87 / 0.28, 0.70 / 0.46 (with the axis's σ at 0.5° once the arm's filters restart
    from the poses' biases: 13.7 of the tuning range's 13.8; at 0.35° once the trunk's
    restarts from its whole pose bias: held out 12.6, the forward lean better, 45.3 →
    12.6). Not alike per kind: a sway
    whose power sits lower than the poses' span shows (the random sway's 1/f) was
    under-told (held-out random 13 and 15: side 1.11° and 1.44° against σ 0.42° and
    0.44°), a sine over-told. Since the side lean's σ is told under a pink spectrum
    (``calibrate.SWAY_ERROR_SLOPE``; est13) the random sway is honest
    (``test_a_red_sways_centre_is_as_sure_as_it_says``: random 0.42 / 1.21) and the sines
    over-told more (irregular 0.24 / 0.23, sine 0.16 / 0.09): the side lean is held to
    never under-told, kind by kind (each kind's 10-kit sum under χ²'s 99.5 % point; the
    30-kit sum 8.2 / 15.3 is under the range's 13.8 on tuning seeds: a σ that cannot tell
    a sine from a red sway over 7.5 s says the larger), the forward lean to the range."""
    from scipy.stats import chi2

    sums, per_kind, side_sums = np.zeros(2), {}, {}
    for kind in ("random", "irregular", "sine"):
        z2 = []
        for seed in seeds:
            sim = random_sway_kit(seed) if kind == "random" else simulate(
                sway_config(seed)) if kind == "sine" else simulate(
                replace(sway_config(seed), trunk_sway=None), motion=replace(
                    exercise_motion("reach", calibration=True),
                    trunk=irregular_sway(seed, *sway_config(seed).trunk_sway)))
            side, forward, side_sd, forward_sd = upright_errors(sim, monkeypatch)
            z2.append(((side / side_sd) ** 2, (forward / forward_sd) ** 2))
        per_kind[kind] = np.mean(z2, axis=0)
        side_sums[kind] = float(np.sum(z2, axis=0)[0])
        sums += np.sum(z2, axis=0)
    n = 3 * len(seeds)
    low, high = chi2.ppf(0.005, n), chi2.ppf(0.995, n)
    print("normalised squared error per kit, side / forward: " + ", ".join(
        f"{k} {v[0]:.2f} / {v[1]:.2f}" for k, v in per_kind.items())
        + f"; sums {sums[0]:.1f} / {sums[1]:.1f} of {low:.1f}–{high:.1f} ({n} kits)")
    assert all(total <= chi2.ppf(0.995, len(seeds)) for total in side_sums.values())
    assert low <= sums[1] <= high


@pytest.mark.parametrize("seeds", [range(1, 11), range(11, 21)], ids=["tuning", "held-out"])
def test_a_red_sways_centre_is_as_sure_as_it_says(seeds, monkeypatch):
    """The random sway (``random_sway``: its power below 0.1 Hz, under ¾ of a cycle in the
    poses' 7.5 s) is the red one a trunk sways with: the 9-axis calibration's side lean (the
    sway's centre) is off by about the σ it gives, each kind on its own (10 kits, 1 degree
    of freedom each, within χ²'s 0.5–99.5 % range). Before (issue 18, est13), the σ taken
    from a flat band was under-told on a red sway: held-out random 11/13/15/18 2–3.3 σ off,
    sum 32.6 of 2.2–25.2 (tuning 10.8, lucky draws)."""
    from scipy.stats import chi2

    z2 = []
    for seed in seeds:
        side, _, side_sd, _ = upright_errors(random_sway_kit(seed), monkeypatch)
        z2.append((side / side_sd) ** 2)
        print(f"random sway seed {seed}: side lean off {side:+.2f}°, σ {side_sd:.2f}°")
    low, high = chi2.ppf(0.005, len(z2)), chi2.ppf(0.995, len(z2))
    print(f"side lean's normalised squared error: sum {sum(z2):.1f} of {low:.1f}–{high:.1f}")
    assert low <= sum(z2) <= high

def session_side_lean(sim, monkeypatch) -> tuple[float, float, bool]:
    """The whole session of ``sim`` through the pipeline: its thorax's side lean as the
    calibration took it (the sway's centre over the poses) against the simulator's mounting
    [deg], the side lean's σ the session ends with [deg] and whether it warned
    (``trunk-swayed``)."""
    from armtrack.estimator.pipeline import calibrate as calibrate_module

    poses_end = max(p.end for p in sim.recording.calibration)
    centres = []
    fit = calibrate_module._sway_centre

    def spy(t, up, **kwargs):
        found = fit(t, up, **kwargs)
        if t[0] < poses_end:  # the calibration's, not a later span's
            centres.append(found[0])
        return found

    monkeypatch.setattr(calibrate_module, "_sway_centre", spy)
    _, calibration = estimate_recording(sim.recording)
    monkeypatch.undo()
    true = sim.truth.mounts["trunk"].R_segment_sensor  # rows: the thorax's axes, sensor frame
    side = float(np.rad2deg((centres[-1] - true[1]) @ true[2]))  # up along Z: about X
    warned = "trunk-swayed" in {w.code for w in calibration.warnings}
    return side, calibration.lean_sd_deg[0], warned


@pytest.mark.parametrize("seeds", [range(1, 11), range(11, 21)], ids=["tuning", "held-out"])
def test_the_session_tells_how_sure_the_lean_is(seeds, monkeypatch):
    """From the poses' 7.5 s alone the side lean's σ cannot tell a few sines at 0.1–0.2 Hz
    from a red sway and says the larger (``SWAY_ERROR_SLOPE``): the sines' σ was over-told
    2.5–3 times (sine seeds 1–10: normalised squared error 0.16 a kit, sum 1.6, under χ²'s
    0.5 % point), so ``trunk-swayed`` warned on 59 of 60 swaying 9-axis kits at a 3-s N-pose
    (seeds 1–20) though their sides leaned off by 0.01–0.87° but for the red sways'. The
    session that follows shows how this trunk sways: the same centre taken over as long a
    span, shifted along the session, scatters about the trunk's long-run centre by what the
    poses' centre may be off; the σ the session ends with is the calibration's scaled by
    that scatter over what the σ told of the same spans. Per kind (random, irregular,
    sine; 10 kits, 1 degree of freedom each) the side lean is now as sure as it says, both
    ways (χ²'s 0.5–99.5 % range), and every kit whose side leaned off by more than 1° (a
    1° bar's angle, about 0.9° of pronation and 0.6° of shoulder rotation a degree on
    these reaches) is still warned."""
    from scipy.stats import chi2

    low, high = chi2.ppf(0.005, len(seeds)), chi2.ppf(0.995, len(seeds))
    sums, warned, missed = {}, 0, []
    for kind in ("random", "irregular", "sine"):
        z2 = []
        for seed in seeds:
            side, sd, warns = session_side_lean(swaying_kit(kind, seed, True), monkeypatch)
            z2.append((side / sd) ** 2)
            warned += warns
            if abs(side) > 1.0 and not warns:
                missed.append(f"{kind} {seed}")
        sums[kind] = float(np.sum(z2))
    print(f"side lean's normalised squared error, sum of {len(seeds)} kits: "
          + ", ".join(f"{k} {v:.1f}" for k, v in sums.items())
          + f" (range {low:.1f}–{high:.1f}); warned {warned} of {3 * len(seeds)}; off by "
          f"more than 1° and not warned: {missed}")
    assert all(low <= total <= high for total in sums.values()), sums
    assert not missed


@pytest.mark.parametrize("kind, seed", [("random", 18), ("random", 37), ("irregular", 25)])
def test_a_six_axis_lean_that_costs_the_wrist_its_bar_is_warned(kind, seed, monkeypatch):
    """A side lean moves the wrist 0.5–0.65 cm a degree on these reaches: the 6-axis
    kit's 1-cm wrist bar allows less lean than its 2° angle bar, so the warning's level is
    the smaller of the two (``quality.LEAN_SD_MAX_DEG``: 0.77° against 1.0°). These kits
    (random 18 held out, random 37 and irregular 25 seeds no other test scores; 6-axis,
    3-s N-pose) miss the wrist's bar by a side lean of 1.1–1.3°; told by the session
    (``sway.retold_lean``) their σ is 0.86–0.96° — under the angle bar's 1.0°, which warned
    random 18 and 37 only while the σ was over-told (1.17° / 1.10°), never irregular 25."""
    sim = swaying_kit(kind, seed, False)
    side, sd, warned = session_side_lean(sim, monkeypatch)
    estimates, _ = estimate_recording(sim.recording)
    _, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                   sim.truth.positions)
    print(f"6-axis {kind} sway seed {seed}: side lean off {side:+.2f}°, σ {sd:.2f}°, "
          f"warned {warned}; worst {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert wrist_cm > WRIST_BAR_CM and abs(side) > 1.0
    assert warned


def irregular_sway(seed: int, amplitude_deg: float, frequency_hz: float) -> dict[str, Profile]:
    """A sway that is no sine: per axis three incommensurate sines (f, √2 f, 1.24 f; the
    side bend at 0.8 f and half the amplitude), amplitudes 0.7/0.5/0.35 of the case's,
    random phases."""
    rng = np.random.default_rng(5000 + seed)
    frequencies = frequency_hz * np.array([1.0, np.sqrt(2.0), (1 + np.sqrt(5)) / 2 / 1.3])
    amplitudes = np.deg2rad(amplitude_deg) * np.array([0.7, 0.5, 0.35])
    trunk = {}
    for name, scale, rate in (("trunk_flexion", 1.0, 1.0), ("trunk_lateral", 0.5, 0.8)):
        phases = rng.uniform(0, 2 * np.pi, 3)
        trunk[name] = Profile(sines=tuple(Sine(scale * a, rate * f, p) for a, f, p
                                          in zip(amplitudes, frequencies, phases, strict=True)))
    return trunk


@pytest.mark.parametrize("seed", [
    1, 2, 3,
    4, 5])
def test_trunk_sway_irregular(seed):
    """The same kit and sway sizes, but a sway that is a sum of incommensurate sines."""
    config = sway_config(seed)
    motion = replace(exercise_motion(config.exercise),
                     trunk=irregular_sway(seed, *config.trunk_sway))
    sim = simulate(replace(config, trunk_sway=None), motion=motion)
    estimates, _ = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions)
    print(f"irregular sway, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


def random_sway(seed: int, amplitude_deg: float) -> dict[str, Profile]:
    """A low-pass random sway: 30 sines at 0.05–0.5 Hz with 1/f amplitudes (RMS about
    the case's amplitude over √2), random phases; the side bend at half the amplitude."""
    rng = np.random.default_rng(6000 + seed)
    frequencies = rng.uniform(0.05, 0.5, 30)
    amplitudes = 1.0 / np.maximum(frequencies, 0.1)
    amplitudes *= np.deg2rad(amplitude_deg) / np.sqrt(np.sum(amplitudes ** 2))
    trunk = {}
    for name, scale in (("trunk_flexion", 1.0), ("trunk_lateral", 0.5)):
        phases = rng.uniform(0, 2 * np.pi, 30)
        trunk[name] = Profile(sines=tuple(Sine(scale * a, f, p) for a, f, p
                                          in zip(amplitudes, frequencies, phases, strict=True)))
    return trunk


def run_random_sway(config: SimulationConfig, seed: int) -> tuple[str, float, float]:
    """The kit of ``config`` under ``random_sway(seed)`` from the first sample (calibration
    poses included): worst angle, its RMSE [deg], wrist RMSE [cm]."""
    sim = random_sway_kit(seed, config)
    estimates, _ = estimate_recording(sim.recording)
    return score(estimates, sim.truth.t, sim_truth_deg(sim), sim.truth.positions)


@pytest.mark.parametrize("seed", [1, 6, 10])
def test_a_swaying_kit_in_a_clean_field_keeps_its_magnetometers(seed, monkeypatch):
    """A random sway in the earth's field alone (dip 65°): the kit's check of the field
    seen in the calibration poses (``pipeline/magnetic.py``) must read that dip, not the
    filters' tilt error of the first seconds — before, seeds 6 and 10 were flagged
    'magnetic-field-disturbed' (pose dips off by 4.8° and 4.7°; the filters' tilt in the
    T-pose off by 3.3–5.7°: each had taken the sway's rate for a still start's bias) and
    lost every magnetometer (worst angle 10.9° and 189°; now 0.69° and 0.75°)."""
    from armtrack.estimator.pipeline import session as session_module

    config = sway_config(seed)
    motion = replace(exercise_motion(config.exercise, calibration=True),
                     trunk=random_sway(seed, config.trunk_sway[0]))
    sim = simulate(replace(config, trunk_sway=None), motion=motion)
    checked = session_module.disagreeing_sensors
    dips = {}

    def spy(tracks, until, poses):
        dips.update({name: [np.rad2deg(track.pose_field(a, b)[1]) for a, b in poses]
                     for name, track in tracks.items()})
        return checked(tracks, until, poses)

    monkeypatch.setattr(session_module, "disagreeing_sensors", spy)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions)
    off = max(abs(d - 65.0) for pose in dips.values() for d in pose)
    print(f"random sway, seed {seed}: pose dips off by {off:.2f}° at most; {worst} "
          f"{worst_deg:.2f}°, wrist {wrist_cm:.2f} cm; warnings "
          f"{sorted({w.code for w in calibration.warnings})}")
    assert len(dips) == 4 and off < 1.0
    assert "magnetic-field-disturbed" not in {w.code for w in calibration.warnings}


#: Why the 9-axis random sway missed the bar on seeds 4/7/8 (measured, qcf alone per sensor
#: against the truth, from 10.5 s): the field is the earth's alone and no trunk sample is
#: called disturbed; the trunk's heading lagged a wrong bias about the vertical (4.9–6.3
#: mrad/s off at 10.5 s) by bias × tau_mag (4 s: ~1.1–1.4°). That bias was learnt, not
#: left: with no gyroscope bias at all the same seeds' trunks took 4–7 mrad/s about the
#: vertical by 5 s (trunk heading RMS 1.08/0.61/0.78°, pipeline 1.51/0.82/1.05° on s4/7/8).
#: It came from the first 2-s heading windows (qcf's field-turning windows, before any
#: rest): a tilt error ε about magnetic north turns the field's heading by ε·tan(dip),
#: 2.1 ε at 65°, and the tilt's warm-up moves ε by tenths of a degree, which the first
#: window takes for drift (irregular s4, no bias: 12 mrad against its 4-mrad noise, a
#: step of 7.4 mrad/s). Keeping the warm-up's tilt changes out of those windows (five
#: ways, bench/README.md) removed the false bias but let a true one in more slowly
#: (irregular s2 0.58 → 1.54°). What holds it off: the trunk's filter restarted at
#: calibration from the vertical bias the held poses show, with its covariance
#: (``calibrate.biases_from_poses``, as on a 6-axis kit; the arm sensors, whose
#: magnetometers hold their headings, keep theirs): worst angle seeds 4/7/8
#: 1.48/1.06/1.24° → 0.48/0.38/0.61°, irregular seed 4 2.20 → 0.95°; held-out seeds
#: 11–20 within the bars 3 → 5 of 10 (sine seeds 6/9, held out, 0.67/0.72 → 1.21/1.24°).


@pytest.mark.parametrize("seed", [
    1, 2, 3,
    4, 5, 6, 7, 8,
    pytest.param(9, marks=pytest.mark.xfail(strict=True, reason=(
        "measured shoulder rotation 1.28°, wrist 0.71 cm (forearm pronation 1.17°, 0.58 cm "
        "before the trunk's filter restarted from its whole pose bias, not its vertical "
        "part alone; shoulder rotation 1.48°, 0.99 cm "
        "before the arm's filters restarted from the poses' biases; 1.51°, 1.01 cm before "
        "the poses' bias covariance was made honest; 1.85°, 1.28 cm before the upright "
        "was the sway's centre): the calibration — with the true sensor-to-segment rotations "
        "0.19°, 0.13 cm (0.41°, 0.20 cm with the thorax's side lean alone taken out); the "
        "sway's centre 1.49° off in side lean (σ 1.27°, 0.77° told under a flat band; the "
        "plain mean 2.03°), a lean the sway kept over the poses' 7.5 s, which no sensor "
        "tells from a tilted mounting then; its calibration warns (trunk-swayed), and held "
        "as long as the live view guides (its 20-s cap) the kit is 0.17°: "
        "test_a_guided_npose_pins_the_trunk_and_meets_the_bar"))),
    10])
def test_a_swaying_kit_in_a_clean_field_meets_the_bar(seed):
    """The 9-axis kit under the low-pass random sway (the earth's field alone, the case's
    biases, no sensor ever rests): every angle within 1°, the wrist within 1 cm."""
    worst, worst_deg, wrist_cm = run_random_sway(sway_config(seed), seed)
    print(f"random sway 9-axis, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[True] and wrist_cm <= WRIST_BAR_CM


def guided_npose_s(kind: str, seed: int, nine_axis: bool) -> tuple[float, float | None]:
    """How long the live guide (``live_status.trunk_guide``: ``calibrate.held_side_lean_sd_deg``
    and ``quality.trunk_hold_guide``) keeps this swaying kit in its N-pose, polled every 0.5 s
    from the shared protocol's 3 s on: the N-pose's end [s] (its window starts at 0.5 s) and
    the side lean's σ then [deg]. The sway is a function of time, so a kit held the guide's
    cap shows every shorter hold."""
    from armtrack.estimator.calibration.quality import GUIDED_HOLD_MAX_S, trunk_hold_guide
    from armtrack.estimator.pipeline.calibrate import held_side_lean_sd_deg

    start = 0.5
    trunk = swaying_kit(kind, seed, nine_axis, npose_s=start + GUIDED_HOLD_MAX_S
                        ).recording.sensors["trunk"]
    for end in np.arange(3.0, start + GUIDED_HOLD_MAX_S + 0.01, 0.5):
        held = (trunk.t >= start) & (trunk.t <= end)
        sd = held_side_lean_sd_deg(trunk.t[held], trunk.acc[held])
        if not trunk_hold_guide(sd, float(end) - start)["keep_holding"]:
            return float(end), sd
    return start + GUIDED_HOLD_MAX_S, sd


#: The kits that miss the bars with the shared protocol's 3-s N-pose by the trunk's side
#: lean (bench/README.md): tuning 9-axis random 9 (the strict xfail above, 1.28°) and 6-axis
#: sine 4 (1.32°, its abduction axis); held out 9-axis random 11 / 13 / 15 / 18 and 6-axis
#: random 11 / 15 / 18.
@pytest.mark.parametrize("nine_axis, kind, seed", [
    (True, "random", 9), (False, "sine", 4),
    (True, "random", 11), (True, "random", 13), (True, "random", 15), (True, "random", 18),
    (False, "random", 11), (False, "random", 15), (False, "random", 18)])
def test_a_guided_npose_pins_the_trunk_and_meets_the_bar(nine_axis, kind, seed):
    """The live view asks for the N-pose to be held until the sway's centre has pinned the
    thorax's side lean (σ, at the 95 % bound of the sway's size, within
    ``quality.LEAN_PINNED_SD_DEG``; 20 s at most); the kit held that long meets the bars
    (1° / 2° without magnetometers, 1 cm), and its calibration does not warn of the sway.
    Measured (est13): holds of 17–20 s (random 9 to the 20-s cap, σ's bound 0.38°: held
    that long it is 0.17°); before, at 3 s, 1.09–1.78° or over 1 cm. No assumption of an
    upright mean posture: the lean is the trunk's own, over the poses."""
    from armtrack.estimator.simulation.scenarios import SCORED_FROM_S, calibration_offset

    npose_s, sd = guided_npose_s(kind, seed, nine_axis)
    sim = swaying_kit(kind, seed, nine_axis, npose_s=npose_s)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions,
                                       scored_from=SCORED_FROM_S + calibration_offset(npose_s))
    print(f"{'9' if nine_axis else '6'}-axis {kind} sway, seed {seed}: N-pose held to "
          f"{npose_s:.1f} s (side lean σ {sd:.2f}°); {worst} {worst_deg:.2f}°, wrist "
          f"{wrist_cm:.2f} cm; lean σ {calibration.lean_sd_deg[0]:.2f}/"
          f"{calibration.lean_sd_deg[1]:.2f}°")
    assert "trunk-swayed" not in {w.code for w in calibration.warnings}
    assert worst_deg <= ANGLE_BAR_DEG[nine_axis] and wrist_cm <= WRIST_BAR_CM


#: Kits on which the guide once said 'steady' after 2.5–4 s while the calibration then
#: warned of the sway (seeds no other test scores, found replaying the guide on seeds
#: 21–30): 9-axis irregular 21 (σ 0.27° at 3 s, the calibration's 0.60°), 25 (0.34° at
#: 4.5 s, 0.95°), sine 26 (0.35°, 1.06°), 6-axis sine 26 (0.35°, 1.08°).
@pytest.mark.parametrize("nine_axis, kind, seed", [
    (True, "irregular", 21), (True, "irregular", 25), (True, "sine", 26), (False, "sine", 26)])
def test_the_guides_steady_is_not_contradicted_by_the_calibration(nine_axis, kind, seed):
    """A trunk caught in a slow stretch of its sway barely moves over the first seconds:
    the sway's size, from the scatter over so short a span, has few degrees of freedom, and
    its point estimate can be far under the sway's. The guide says 'steady' only when the
    lean is pinned at the 95 % bound of that estimate (``calibrate.GUIDE_CONFIDENCE``), so
    the calibration of a kit held that long does not warn of the sway: now steady at 5.0 /
    18.5 / 18.0 / 18.0 s, the calibration's σ 0.42 / 0.12 / 0.11 / 0.11° (a bound only
    before 7.5 s of span: irregular 25 steady at 8.5 s, the calibration 0.53°)."""
    npose_s, sd = guided_npose_s(kind, seed, nine_axis)
    sim = swaying_kit(kind, seed, nine_axis, npose_s=npose_s)
    calibration = calibration_only(sim.recording, npose_s + 6.0)
    print(f"{'9' if nine_axis else '6'}-axis {kind} {seed}: steady at {npose_s:.1f} s (σ "
          f"{sd:.2f}°); the calibration's side lean σ {calibration.lean_sd_deg[0]:.2f}°; "
          f"{sorted({w.code for w in calibration.warnings})}")
    assert "trunk-swayed" not in {w.code for w in calibration.warnings}

def test_a_still_trunk_is_steady_at_once():
    """The guide asks nothing more of a trunk that does not sway: the same kit with a
    still trunk is steady at the shared protocol's 3 s (its side lean's σ ~0.02°)."""
    from armtrack.estimator.calibration.quality import trunk_hold_guide
    from armtrack.estimator.pipeline.calibrate import held_side_lean_sd_deg

    trunk = simulate(replace(sway_config(9), trunk_sway=None)).recording.sensors["trunk"]
    held = (trunk.t >= 0.5) & (trunk.t <= 3.0)
    sd = held_side_lean_sd_deg(trunk.t[held], trunk.acc[held])
    guide = trunk_hold_guide(sd, 2.5)
    print(f"still trunk at 3 s: σ {sd:.3f}°; {guide['message']}")
    assert guide["pinned"] and not guide["keep_holding"]
    assert "Trunk steady" in guide["message"]

@pytest.mark.parametrize("seed", [*range(1, 9), 11])
def test_long_six_axis_session_with_drifting_bias_and_rests(seed):
    """11 minutes, three rounds of shoulder sets with 20 s rests, upper arm, forearm and
    hand, no trunk sensor: each sensor's heading drift between two rests (as short as the
    pauses between repetitions) is taken back at the second, and the arm's heading is the
    mean of its sensors' own, each weighed by how little it has turned (at rest a heading
    holds). A joint turns what it remembers only by the part of a step that drifted before
    each remembered sample: seeds 5 and 7 (wrist flexion 2.11°, 2.22°, the forearm–hand
    tie held through blind stretches) 0.37°, 0.81°. Seed 11 (held out, never tuned on)
    missed at 2.22° (shoulder rotation): the noise of a short pause's mean at 50 Hz, each
    knot taken as exact; the take-back is now a Kalman filter of the bias and the heading
    integral, each knot weighed by its variance: 1.07°; seeds 1–8 worst 0.39–1.92°."""
    config = SimulationConfig(exercise="shoulder_sets", seed=seed, height_m=body(seed),
                              nine_axis=False, rate_hz=(100.0, 50.0)[seed % 2],
                              gyro_bias_max=0.02, errors=drifting(seed))
    worst, worst_deg, wrist_cm, _ = run(config)
    print(f"11 min 6-axis, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


@functools.cache
def no_rests(seed: int, nine_axis: bool):
    """14 minutes of shoulder sets one after the other, a drifting bias, a clean field."""
    return run(SimulationConfig(exercise="shoulder_sets_no_rest", seed=seed,
                                height_m=body(seed), rate_hz=(100.0, 50.0)[seed % 2],
                                gyro_bias_max=0.02, errors=drifting(seed),
                                nine_axis=nine_axis))


@functools.cache
def nonstop(seed: int, nine_axis: bool):
    """As ``no_rests`` with no pause between repetitions either: nothing ever rests (the
    pauses between repetitions show a 6-axis sensor its bias, ``pipeline/drift.py``)."""
    return run(SimulationConfig(exercise="shoulder_sets_nonstop", seed=seed,
                                height_m=body(seed), rate_hz=(100.0, 50.0)[seed % 2],
                                gyro_bias_max=0.02, errors=drifting(seed),
                                nine_axis=nine_axis))


@pytest.mark.parametrize("seed", [1, 2])
def test_nine_axis_beats_six_axis_in_a_clean_field_without_rests(seed):
    """The magnetometer holds the headings the gyroscopes lose (not won by ignoring it)."""
    nine, six = nonstop(seed, True), nonstop(seed, False)
    print(f"nothing rests, seed {seed}: 9-axis {nine[0]} {nine[1]:.2f}°, {nine[2]:.2f} cm; "
          f"6-axis {six[0]} {six[1]:.2f}°, {six[2]:.2f} cm")
    assert not nine[3].warnings
    assert nine[1] < six[1] / 4 and nine[2] < six[2] / 4


@pytest.mark.parametrize("seed", [1, 2])
def test_nine_axis_without_rests_meets_the_bar(seed):
    """Seed 2 was 1.03° (the drifting bias learnt only from the field); qcf's tilt windows
    (the bias from the tilt corrections as the sensor turns) made it 0.88°."""
    nine = no_rests(seed, True)
    assert nine[1] <= ANGLE_BAR_DEG[True] and nine[2] <= WRIST_BAR_CM


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_six_axis_without_rests_between_sets_meets_the_bar(seed):
    """14 minutes of sets one after the other: only the pauses between repetitions show
    the 6-axis sensors their biases. While each joint turned its whole memory with every
    step taken back (before it turned each remembered sample by the part of the step's gap
    it had seen): wrist flexion 3.29/4.56/1.69/3.69°; now 0.77/0.94/1.11/0.68° worst (not
    tuned on)."""
    six = no_rests(seed, False)
    print(f"14 min 6-axis, no rests between sets, seed {seed}: {six[0]} {six[1]:.2f}°, "
          f"wrist {six[2]:.2f} cm")
    assert six[1] <= ANGLE_BAR_DEG[False] and six[2] <= WRIST_BAR_CM


def feed_rows_in_chunks(recording, rng, pipelines: list | None = None):
    """As a live server feeds a pipeline: stream rows ``[t, acc, gyr, mag]`` (NaN mag on
    a 6-axis kit) in random chunks of 1–40 rows, sensors interleaved in time (the pipeline
    appended to ``pipelines`` if given)."""
    from armtrack.estimator.pipeline import Pipeline, PipelineConfig
    from armtrack.estimator.recording import Mark

    config = PipelineConfig(side=recording.side, lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors))
    pipeline = Pipeline(config)
    for pose in recording.calibration:
        pipeline.add_mark(Mark(pose.start, pose.name))
        pipeline.add_mark(Mark(pose.end, f"end:{pose.name}"))
    rows = {name: np.column_stack([st.t, st.acc, st.gyr, st.mag if st.mag is not None
                                   else np.full((len(st.t), 3), np.nan)])
            for name, st in recording.sensors.items()}
    cursors = dict.fromkeys(rows, 0)
    parts = []
    while any(cursors[s] < len(r) for s, r in rows.items()):
        name = min((s for s, r in rows.items() if cursors[s] < len(r)),
                   key=lambda s: rows[s][cursors[s], 0])
        a = cursors[name]
        b = min(a + int(rng.integers(1, 40)), len(rows[name]))
        pipeline.feed_rows(name, np.ascontiguousarray(rows[name][a:b]))
        cursors[name] = b
        parts.append(pipeline.poll())
    parts.append(pipeline.finish())
    if pipelines is not None:
        pipelines.append(pipeline)
    return parts


@pytest.mark.parametrize("start_disturbance", [None, (20.0, 30.0)])
def test_packed_and_disturbed_kits_streamed_in_chunks_equal_batch(start_disturbance):
    """The re-timing of packed samples and the magnetometer decision at calibration are
    causal: chunks of any size, sensors interleaved, give the batch numbers."""
    from armtrack.estimator.arm import REPORTED_ANGLES
    from armtrack.estimator.pipeline import Estimates
    from test_pipeline import feed_in_chunks

    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=5, pack_size=4,
                                    start_disturbance_s=start_disturbance))
    batch, calibration = estimate_recording(sim.recording)
    assert bool(calibration.warnings) == (start_disturbance is not None)
    for parts in (feed_in_chunks(sim.recording, np.random.default_rng(9)),
                  feed_rows_in_chunks(sim.recording, np.random.default_rng(10))):
        stream = Estimates.concatenate(parts)
        np.testing.assert_array_equal(stream.t, batch.t)
        for k in REPORTED_ANGLES:
            np.testing.assert_allclose(stream.angles[k], batch.angles[k], atol=1e-9, rtol=0)


def test_six_axis_swaying_kit_streamed_in_chunks_equals_batch():
    """The 6-axis calibration's second pass and the trunk filter's restart from the poses'
    bias happen once, at calibration, on the samples up to then: chunks of any size,
    sensors interleaved, give the batch numbers; the lean's σ the session tells again at
    its end (``sway.retold_lean``) and its warning too."""
    from armtrack.estimator.arm import REPORTED_ANGLES
    from armtrack.estimator.pipeline import Estimates
    from test_pipeline import feed_in_chunks

    sim = simulate(six_axis_sway(1, sway_config(1).gyro_bias_max))
    batch, calibration = estimate_recording(sim.recording)
    streamed: list = []
    for parts in (feed_in_chunks(sim.recording, np.random.default_rng(11)),
                  feed_rows_in_chunks(sim.recording, np.random.default_rng(12), streamed)):
        stream = Estimates.concatenate(parts)
        np.testing.assert_array_equal(stream.t, batch.t)
        for k in REPORTED_ANGLES:
            np.testing.assert_allclose(stream.angles[k], batch.angles[k], atol=1e-9, rtol=0)
    print(f"lean σ batch {calibration.lean_sd_deg}, streamed {streamed[0].calibration.lean_sd_deg}")
    assert calibration.lean_sd_deg != calibration_only(sim.recording).lean_sd_deg  # told again
    np.testing.assert_allclose(streamed[0].calibration.lean_sd_deg, calibration.lean_sd_deg,
                               rtol=1e-9, atol=0)
    assert streamed[0].calibration.warnings == calibration.warnings


def test_the_elbow_fits_its_drift_only_where_no_stillness_taught_the_biases():
    """The elbow's constraint fits how fast its sensors' headings drift apart on a swaying
    6-axis kit (nothing rests: the biases are learnt in motion only) and keeps the mean
    where the sensors started still (a still start or a rest taught each its bias: RING's
    chain, whose foam-mounted trial 2 the rate cost up to 0.8° at the wrist) or where
    magnetometers hold the headings."""
    from armtrack.estimator.pipeline import run_recording

    def elbow_rate_prior(recording):
        pipeline = run_recording(recording)
        pipeline.finish()
        return pipeline._constraints["forearm"].rate_prior

    swaying = simulate(six_axis_sway(1, sway_config(1).gyro_bias_max)).recording
    still = simulate(SimulationConfig(exercise="elbow_flexion", seed=31,
                                      nine_axis=False)).recording
    nine = simulate(sway_config(1)).recording
    found = {"swaying": elbow_rate_prior(swaying), "still start": elbow_rate_prior(still),
             "9-axis": elbow_rate_prior(nine)}
    print(f"elbow's rate prior: {found}")
    assert np.isfinite(found["swaying"])
    assert np.isinf(found["still start"]) and np.isinf(found["9-axis"])


@pytest.mark.parametrize("seed", [1, 2, 6, 10])
def test_six_axis_random_sway(seed):
    """The 6-axis kit under the low-pass random sway, with the case's biases: seed 1
    15.98° → 1.95° (wrist 0.97 cm); seeds 2/6/10 1.86/2.82/2.97° (wrist 1.19/0.87/1.90 cm)
    → 1.24/0.91/1.34° (0.97/0.81/0.96 cm) once every sensor's filter starts from the
    biases the held poses show (``biases_from_poses``)."""
    worst, worst_deg, wrist_cm = run_random_sway(
        six_axis_sway(seed, sway_config(seed).gyro_bias_max), seed)
    print(f"6-axis random sway, seed {seed}: {worst} {worst_deg:.2f}°, wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM


@pytest.mark.parametrize("seed", [
    1, 2, 3, 4, 5])
def test_six_axis_irregular_sway(seed):
    """The 6-axis kit under the sway of incommensurate sines, with the case's biases:
    seeds 2/4/5 3.83/2.37/1.56° (wrist 2.50/1.73/1.07 cm) → 0.70/1.59/0.71° (0.46/0.88/
    0.36 cm) once every sensor's filter starts from the biases the held poses show
    (``biases_from_poses``). Seed 3 missed at 2.00°, 1.49 cm (1.85°, 1.38 cm with the
    upright as the sway's centre): the trunk's bias about the vertical from the poses
    1.9 mrad/s off while its σ said 0.3; with the sway's acceleration in the tilt drifts'
    model (``_tilt_bias``) 0.08 mrad/s off: 1.09°, 0.85 cm (seeds 1–5 0.76/0.59/1.85/1.48/
    0.74° → 0.80/0.48/1.09/1.34/0.70°)."""
    config = six_axis_sway(seed, sway_config(seed).gyro_bias_max)
    motion = replace(exercise_motion(config.exercise, calibration=True),
                     trunk=irregular_sway(seed, *config.trunk_sway))
    sim = simulate(replace(config, trunk_sway=None), motion=motion)
    estimates, _ = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions)
    print(f"6-axis irregular sway, seed {seed}: {worst} {worst_deg:.2f}°, "
          f"wrist {wrist_cm:.2f} cm")
    assert worst_deg <= ANGLE_BAR_DEG[False] and wrist_cm <= WRIST_BAR_CM
