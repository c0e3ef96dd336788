"""The estimation pipeline: accuracy against ground truth (the shared recordings and the
project's simulator), batch equal to streaming, calibration rules and warnings."""

import numpy as np
import pytest
from armtrack.estimator.arm import REPORTED_ANGLES
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, estimate_recording
from armtrack.estimator.recording import Mark, read_recording
from armtrack.estimator.simulation import (
    ImuErrors,
    Motion,
    Profile,
    Ramp,
    SimulationConfig,
    Sine,
    exercise_motion,
    simulate,
)
from armtrack.estimator.simulation.scenarios import EXERCISE_START_S, SCORED_FROM_S

#: Issue 4's bar: every angle's RMSE over the exercise part, and the wrist's position
#: relative to the shoulder.
ANGLE_BAR_DEG = {True: 1.0, False: 2.0}  # nine_axis → bar
WRIST_BAR_CM = 1.0

SHARED = ["elbow_flexion", "shoulder_abduction", "shoulder_flexion", "wrist_flexion",
          "pronation", "left_reach_50hz", "elbow_6axis", "elbow_6axis_long", "trunk_reach",
          "abduction_120"]
#: Recordings where the estimator does not meet the bar yet (measured figures in the
#: reason); strict, so the day one passes the mark must go.
KNOWN_GAPS: dict[str, str] = {}


def score(estimates, truth_t, truth_angles, truth_positions, scored_from=SCORED_FROM_S):
    """Worst angle RMSE [deg] (and its name) and the wrist-from-shoulder RMSE [cm].
    ``truth_angles`` in degrees, ``truth_positions`` in metres (thorax frame)."""
    m = estimates.t >= scored_from
    t = estimates.t[m]
    rmse = {k: float(np.sqrt(np.mean((np.rad2deg(estimates.angles[k][m])
                                      - np.interp(t, truth_t, truth_angles[k])) ** 2)))
            for k in REPORTED_ANGLES}
    rel_true = np.stack([np.interp(t, truth_t, truth_positions["wrist"][:, a]
                                   - truth_positions["shoulder"][:, a]) for a in range(3)], -1)
    rel_est = estimates.positions["wrist"][m] - estimates.positions["shoulder"][m]
    wrist_cm = 100 * float(np.sqrt(np.mean(np.sum((rel_est - rel_true) ** 2, axis=1))))
    worst = max(rmse, key=rmse.get)
    return worst, rmse[worst], wrist_cm


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=KNOWN_GAPS[n]))
    if n in KNOWN_GAPS else n for n in SHARED])
def test_shared_recordings_meet_the_bar(recordings, recordings_dir, name):
    """On the shared files where present, else on the stand-ins (the stand-in
    trunk_reach's trunk sways through the poses as the shared file's: 0.92°, 0.99 cm)."""
    recording = read_recording(recordings_dir / f"{name}.csv")
    truth = np.genfromtxt(recordings_dir / f"{name}.truth.csv",
                          delimiter=",", names=True)
    estimates, calibration = estimate_recording(recording)
    positions = {p: np.stack([truth[f"{p}_{a}"] for a in "xyz"], -1)
                 for p in ("shoulder", "wrist")}
    worst, worst_deg, wrist_cm = score(estimates, truth["t"], truth, positions)
    nine_axis = all(s.nine_axis for s in recording.sensors.values())
    print(f"{recordings.source} {name}: worst angle {worst} RMSE {worst_deg:.2f}°, wrist "
          f"{wrist_cm:.2f} cm ({calibration.method}, {'9' if nine_axis else '6'}-axis)")
    assert calibration.method == "two-pose" and not calibration.warnings
    assert worst_deg <= ANGLE_BAR_DEG[nine_axis], (worst, worst_deg)
    assert wrist_cm <= WRIST_BAR_CM


def sim_truth_deg(sim):
    return {k: np.rad2deg(v) for k, v in sim.truth.angles.items()}


SIMULATED = {
    "left_50hz_lossy": SimulationConfig(exercise="reach", side="left", rate_hz=50, seed=11,
                                        lost_fraction=0.03, jitter_s=0.002, height_m=1.58),
    "clavicle_sensor": SimulationConfig(exercise="shrug", seed=12, height_m=1.92,
                                        sensors=("clavicle", "upper_arm", "forearm", "hand")),
    "six_axis_drinking": SimulationConfig(exercise="drinking", nine_axis=False, seed=13),
    "abduction_past_90": SimulationConfig(exercise="abduction_120", seed=14),
    "long_6axis_drifting_bias": SimulationConfig(
        exercise="long_session", nine_axis=False, seed=15,
        errors=ImuErrors(gyro_noise=0.004, acc_noise=0.04, gyro_bias_walk=2e-4)),
    "long_6axis_left": SimulationConfig(
        exercise="long_session", side="left", nine_axis=False, seed=18,
        errors=ImuErrors(gyro_noise=0.004, acc_noise=0.04, gyro_bias_walk=2e-4)),
    "magnet_near_hand": SimulationConfig(exercise="reach", magnet_near_hand=True, seed=16),
    "tall_body_shoulder_flexion": SimulationConfig(exercise="shoulder_flexion", seed=17,
                                                   height_m=2.02),
}


@pytest.mark.parametrize("name", sorted(SIMULATED))
def test_simulated_sessions_meet_the_bar(name):
    config = SIMULATED[name]
    sim = simulate(config)
    estimates, calibration = estimate_recording(sim.recording)
    worst, worst_deg, wrist_cm = score(estimates, sim.truth.t, sim_truth_deg(sim),
                                       sim.truth.positions)
    print(f"simulated {name}: worst angle {worst} RMSE {worst_deg:.2f}°, wrist "
          f"{wrist_cm:.2f} cm")
    assert calibration.method == "two-pose"
    assert worst_deg <= ANGLE_BAR_DEG[config.nine_axis], (worst, worst_deg)
    assert wrist_cm <= WRIST_BAR_CM


def feed_in_chunks(recording, rng, poll_every=3, gyr_bias_priors=None):
    """Feed a recording in random chunks, sensors interleaved in time, polling as we go."""
    config = PipelineConfig(side=recording.side, lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors))
    pipeline = Pipeline(config, gyr_bias_priors=gyr_bias_priors)
    for mark in [Mark(p.start, p.name) for p in recording.calibration] + \
            [Mark(p.end, f"end:{p.name}") for p in recording.calibration]:
        pipeline.add_mark(mark)
    cursors = dict.fromkeys(recording.sensors, 0)
    parts, step = [], 0
    while any(cursors[s] < len(st.t) for s, st in recording.sensors.items()):
        name = min((s for s, st in recording.sensors.items() if cursors[s] < len(st.t)),
                   key=lambda s: recording.sensors[s].t[cursors[s]])
        stream, a = recording.sensors[name], cursors[name]
        b = min(a + int(rng.integers(1, 400)), len(stream.t))
        pipeline.feed(name, stream.t[a:b], stream.acc[a:b], stream.gyr[a:b],
                      None if stream.mag is None else stream.mag[a:b])
        cursors[name] = b
        step += 1
        if step % poll_every == 0:
            parts.append(pipeline.poll())
    parts.append(pipeline.finish())
    return parts


def test_streaming_in_chunks_equals_batch():
    sim = simulate(SimulationConfig(exercise="abduction_120", seed=21, lost_fraction=0.02,
                                    jitter_s=0.001))
    batch, _ = estimate_recording(sim.recording)
    from armtrack.estimator.pipeline import Estimates

    parts = feed_in_chunks(sim.recording, np.random.default_rng(3))
    stream = Estimates.concatenate(parts)
    np.testing.assert_array_equal(stream.t, batch.t)
    for k in REPORTED_ANGLES:
        np.testing.assert_allclose(stream.angles[k], batch.angles[k], atol=1e-9, rtol=0)
    for p in stream.positions:
        np.testing.assert_allclose(stream.positions[p], batch.positions[p], atol=1e-9, rtol=0)
    # nothing before calibration is final (the end of the T-pose), then everything from
    # the first sample on
    assert all(len(p) == 0 for p in parts[:2])
    assert stream.t[0] == sim.recording.sensors["upper_arm"].t[0]


def test_estimates_are_at_the_reference_sensor_times():
    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=22, lost_fraction=0.05))
    estimates, _ = estimate_recording(sim.recording)
    np.testing.assert_array_equal(estimates.t, sim.recording.sensors["upper_arm"].t)
    assert not any(np.isnan(v).any() for v in estimates.angles.values())
    # the segments in the world (for the 3D view): the model's, near the true ones
    from scipy.spatial.transform import Rotation

    for sensor in ("upper_arm", "forearm", "hand"):
        true = sim.truth.R_world_sensor[sensor] @ sim.truth.mounts[sensor].R_segment_sensor.T
        t_true = sim.recording.sensors[sensor].t
        i = np.searchsorted(t_true, estimates.t).clip(0, len(t_true) - 1)
        keep = np.abs(t_true[i] - estimates.t) < 1e-9
        error = Rotation.from_matrix(estimates.R_world_segment[sensor][keep]).inv() * \
            Rotation.from_matrix(true[i[keep]])
        rmse = float(np.sqrt(np.mean(np.rad2deg(error.magnitude()) ** 2)))
        print(f"{sensor} segment in the world: {rmse:.2f}° RMSE")
        assert rmse < 1.0


def calibration_motion(tpose_deg=90.0, wobble_deg=0.0):
    """The calibration sequence with a T-pose of ``tpose_deg`` and an elbow that wobbles
    by ``wobble_deg`` during the N-pose, then elbow flexion."""
    joints = dict(exercise_motion("elbow_flexion").joints)
    joints["shoulder_abduction"] = Profile(ramps=(Ramp(4.0, np.deg2rad(tpose_deg), 0.25),
                                                  Ramp(9.25, -np.deg2rad(tpose_deg), 0.1875)))
    if wobble_deg:
        joints["elbow_flexion"] = joints["elbow_flexion"] + Profile(
            sines=(Sine(np.deg2rad(wobble_deg), 1.5),))
    return Motion(joints=joints)


def test_warnings_for_a_bad_t_pose_and_a_pose_not_held_still():
    config = SimulationConfig(exercise="elbow_flexion", seed=23)
    bad_tpose = simulate(config, motion=calibration_motion(tpose_deg=60))
    _, calibration = estimate_recording(bad_tpose.recording)
    assert [w.sensor for w in calibration.warnings if w.code == "not-a-tpose"] == ["upper_arm"]
    wobbly = simulate(config, motion=calibration_motion(wobble_deg=15))
    _, calibration = estimate_recording(wobbly.recording)
    codes = {(w.code, w.sensor) for w in calibration.warnings}
    assert ("pose-not-still", "forearm") in codes and ("pose-not-still", "upper_arm") not in codes
    still = [w.message for w in calibration.warnings if w.code == "pose-not-still"]
    print(still)
    assert all(m.startswith(("the forearm sensor was not still during the",  # and the hand
                             "the hand sensor was not still during the")) for m in still)


def test_a_whole_body_moving_through_the_poses_is_said_once_per_pose_in_plain_words():
    """A trunk swaying through both poses moves every sensor of the kit: one warning per
    pose saying so (not one per sensor and pose — eight lines that said the same), in
    words without code names ("upper arm", not "upper_arm")."""
    from test_estimation_hard_cases import sway_config

    _, calibration = estimate_recording(simulate(sway_config(1)).recording)
    still = [w for w in calibration.warnings if w.code == "pose-not-still"]
    for w in calibration.warnings:
        print(w.code, w.sensor, w.message)
    assert [w.sensor for w in still] == [None, None]
    assert [w.message.split(" (")[0] for w in still] == [
        "every sensor moved during the N-pose", "every sensor moved during the T-pose"]
    assert all("back supported" in w.message and "_" not in w.message
               for w in calibration.warnings)


def test_warning_for_swapped_sensors():
    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=24,
                                    sensors=("trunk", "upper_arm", "forearm")))
    from armtrack.estimator.recording import Recording

    streams = dict(sim.recording.sensors)
    streams["trunk"], streams["upper_arm"] = streams["upper_arm"], streams["trunk"]
    swapped = Recording(side="right", sensors=streams, height_m=1.75,
                        calibration=sim.recording.calibration)
    _, calibration = estimate_recording(swapped)
    flagged = {w.sensor for w in calibration.warnings if w.code == "sensor-swapped"}
    assert flagged == {"trunk", "upper_arm"}, calibration.warnings


def test_without_poses_the_default_mounting_is_used_and_said():
    config = SimulationConfig(exercise="elbow_flexion", seed=25, calibration=False,
                              mount_axial_deg=0, mount_tilt_deg=0)
    sim = simulate(config)
    estimates, calibration = estimate_recording(sim.recording)
    assert calibration.method == "default"
    assert [w.code for w in calibration.warnings] == ["default-mounting"]
    worst, worst_deg, _ = score(estimates, sim.truth.t, sim_truth_deg(sim), sim.truth.positions,
                                scored_from=EXERCISE_START_S - 10.0)
    print(f"default mounting, sensors mounted as assumed: worst {worst} {worst_deg:.2f}°")
    assert worst_deg <= ANGLE_BAR_DEG[True]


def test_heading_constraint_recovers_a_forearm_heading_error():
    """A forearm turned 6° about the vertical against its upper arm: the elbow's constraint
    finds the turn once the elbow bends, and says nothing while it is straight. The
    estimate is shrunk toward 0 by its prior (≈ prior / ∫D² dt, under 1% here) and by the
    linearisation: it must land within 15% of the turn, on the right side of 0. While the
    elbow is straight it stays within 0.1° (the prior is small, 0.05 s·rad², so that a
    joint seen bent for a second already corrects: RING's wrist needs it)."""
    from armtrack.estimator.pipeline.constraints import HeadingConstraint
    from armtrack.estimator.rotations import elemental

    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=31))
    R = {s: R @ sim.truth.mounts[s].R_segment_sensor.T
         for s, R in sim.truth.R_world_sensor.items()}
    t = sim.recording.sensors["upper_arm"].t
    turned = elemental("z", np.deg2rad(6.0)) @ R["forearm"]
    whole = HeadingConstraint().update(t, R["upper_arm"][:, :, 2], turned[:, :, 1])
    straight = t < 10.0  # calibration poses: the elbow never bends
    assert np.abs(whole[straight]).max() < np.deg2rad(0.1)
    late = t > 25.0
    print(f"heading constraint: {np.rad2deg(whole[late]).mean():.3f}° found for a -6° turn")
    assert np.all((whole[late] < np.deg2rad(-6.0 * 0.85)) & (whole[late] > np.deg2rad(-6.0)))
    chunked = HeadingConstraint()
    parts = [chunked.update(t[a:a + 700], R["upper_arm"][a:a + 700, :, 2],
                            turned[a:a + 700, :, 1]) for a in range(0, len(t), 700)]
    np.testing.assert_allclose(np.concatenate(parts), whole, atol=1e-12)


def test_heading_constraint_follows_a_drifting_forearm_heading():
    """A forearm whose heading drifts against its upper arm's at 0.2°/s (the two gyroscopes'
    vertical biases differ by 3.5 mrad/s: in a swaying kit neither rests to learn it): the
    elbow's constraint fits the drift's rate, not only its mean over the forgetting time
    (which lags a drift of rate r by up to r·tau, 4° here). After 25 s the fitted line is
    off by at most half what the mean alone is (measured 0.59° against 2.24°)."""
    from armtrack.estimator.pipeline.constraints import DRIFT_RATE_PRIOR, HeadingConstraint
    from armtrack.estimator.rotations import elemental

    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=31))
    R = {s: R @ sim.truth.mounts[s].R_segment_sensor.T
         for s, R in sim.truth.R_world_sensor.items()}
    t = sim.recording.sensors["upper_arm"].t
    drift = np.deg2rad(0.2) * (t - t[0])
    turned = np.einsum("nij,njk->nik", np.stack([elemental("z", h) for h in drift]),
                       R["forearm"])
    late = t > 25.0
    errors = {}
    for name, constraint in (("line", HeadingConstraint(rate_prior=DRIFT_RATE_PRIOR)),
                             ("mean", HeadingConstraint())):
        found = constraint.update(t, R["upper_arm"][:, :, 2], turned[:, :, 1])
        errors[name] = np.rad2deg(np.abs(found[late] + drift[late])).max()
    print(f"heading constraint on a 0.2°/s drift, off at most after 25 s: fitted rate "
          f"{errors['line']:.2f}°, mean alone {errors['mean']:.2f}°")
    assert errors["line"] < 0.5 * errors["mean"]


@pytest.mark.parametrize("name", ["elbow_6axis", "trunk_reach"])
def test_shared_recording_streamed_in_chunks_equals_batch(recordings_dir, name):
    """A 6-axis kit (heading constraints) and one with a trunk sensor, chunked at random."""
    from armtrack.estimator.pipeline import Estimates

    recording = read_recording(recordings_dir / f"{name}.csv")
    batch, _ = estimate_recording(recording)
    stream = Estimates.concatenate(feed_in_chunks(recording, np.random.default_rng(7)))
    np.testing.assert_array_equal(stream.t, batch.t)
    for k in REPORTED_ANGLES:
        np.testing.assert_allclose(stream.angles[k], batch.angles[k], atol=1e-9, rtol=0)


def test_compiled_segment_orientations_equal_the_numpy_path():
    """slerp + quaternion→matrix + heading + mounting, compiled, against the numpy helpers,
    at times between samples, on them, before the first and after the last."""
    from armtrack.estimator.pipeline.segment_kernel import _segment_python, segment_orientations
    from armtrack.estimator.rotations import elemental, quat_slerp, quat_to_matrix
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.005, 0.02, 300))
    q = Rotation.random(300, rng=rng).as_quat(scalar_first=True)
    q[1::2] *= -1  # both signs of the same rotations
    times = np.sort(np.r_[rng.uniform(t[0] - 0.1, t[-1] + 0.1, 500), t[::7]])
    R_ss = Rotation.random(rng=rng).as_matrix()
    j = np.clip(np.searchsorted(t, times, "right") - 1, 0, len(t) - 1)
    k = np.minimum(j + 1, len(t) - 1)
    span = t[k] - t[j]
    u = np.where(span > 0, (times - t[j]) / np.where(span > 0, span, 1), 0).clip(0, 1)
    expected = elemental("z", 0.7) @ quat_to_matrix(quat_slerp(q[j], q[k], u)) @ R_ss
    np.testing.assert_allclose(segment_orientations(t, q, times, R_ss, 0.7), expected,
                               atol=1e-12)
    out = np.empty((len(times), 3, 3))
    _segment_python(t, q, times, R_ss, 0.7, out)
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_swapped_forearm_and_hand_sensors_are_flagged_by_the_joint_residuals():
    """Gravity cannot tell a forearm from a hand sensor in the N- and T-pose; the joints
    can once the wrist moves."""
    from armtrack.estimator.pipeline.quality import residual_warnings
    from armtrack.estimator.recording import Recording

    sim = simulate(SimulationConfig(exercise="wrist_flexion", seed=51))
    good, _ = estimate_recording(sim.recording)
    assert residual_warnings(good, tuple(sim.recording.sensors)) == []
    streams = dict(sim.recording.sensors)
    streams["forearm"], streams["hand"] = streams["hand"], streams["forearm"]
    swapped = Recording(side="right", sensors=streams, height_m=1.75,
                        calibration=sim.recording.calibration)
    estimates, calibration = estimate_recording(swapped)
    assert not any(w.code == "sensor-swapped" for w in calibration.warnings)  # gravity: no
    warnings = residual_warnings(estimates, tuple(streams))
    print([w.message for w in warnings])
    assert [w.code for w in warnings] and all(w.code == "joint-residual" for w in warnings)


@pytest.mark.parametrize("name", SHARED)
def test_repetitions_counted_on_the_estimates_match_the_truth(recordings, name):
    """The counts of the recordings' facts: the shared README's, or the stand-in's
    simulation's (tests/recording_sets.py): the excursions (each turn one), and the
    repetitions as a therapist counts them (a both-ways angle's turn to each side one)."""
    from armtrack.estimator.metrics import (
        BOTH_WAYS,
        CALIBRATION_TAIL_S,
        count_repetitions,
        repetitions_by_angle,
    )

    expected = recordings.facts[name].turns()
    therapist = recordings.facts[name].counts()
    recording = read_recording(recordings.path(name))
    estimates, _ = estimate_recording(recording)
    calibration_end = max(p.end for p in recording.calibration) + CALIBRATION_TAIL_S
    counted = repetitions_by_angle({k: estimates.angles[k] for k in expected},
                                   estimates.t, exclude=[(estimates.t[0], calibration_end)])
    got = {k: len(v) for k, v in counted.items()}
    repetitions = {k: count_repetitions(v, k in BOTH_WAYS) for k, v in counted.items()}
    print(f"{recordings.source} {name}: turns {got} (truth {expected}), repetitions "
          f"{repetitions} (truth {therapist})")
    assert got == expected
    assert repetitions == therapist


def test_a_silent_sensor_can_be_dropped_so_the_others_need_not_wait():
    sim = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=2, seed=3))
    rec = sim.recording
    pipeline = Pipeline(PipelineConfig(side="right", lengths=rec.segment_lengths(),
                                       sensors=("upper_arm", "forearm", "hand")),
                        poses=rec.calibration)
    for name in ("upper_arm", "forearm"):
        s = rec.sensors[name]
        pipeline.feed(name, s.t, s.acc, s.gyr, s.mag)
    assert pipeline.silent_sensors() == ["hand"]
    assert len(pipeline.poll()) == 0  # waiting for the hand
    with pytest.raises(InvalidArgument, match="cannot be dropped"):
        pipeline.drop_sensor("forearm")  # it has data
    pipeline.drop_sensor("hand")
    estimates = pipeline.poll()
    assert len(estimates) > 0.9 * len(rec.sensors["upper_arm"])
    assert np.allclose(estimates.angles["wrist_flexion"], 0.0)  # no hand: the wrist stays 0


def stream_rows(stream, a: int, b: int) -> np.ndarray:
    """Samples a..b of a sensor as the stream protocol's rows (n, 10), NaN magnetometer
    on a 6-axis sensor."""
    rows = np.full((b - a, 10), np.nan)
    rows[:, 0], rows[:, 1:4], rows[:, 4:7] = stream.t[a:b], stream.acc[a:b], stream.gyr[a:b]
    if stream.mag is not None:
        rows[:, 7:10] = stream.mag[a:b]
    return rows


@pytest.mark.parametrize("nine_axis", [True, False], ids=["9-axis", "6-axis"])
def test_feeding_stream_rows_equals_feeding_their_columns(nine_axis, monkeypatch):
    """The live server's ``feed_rows`` (the filter and the copy in one compiled call) gives
    the same estimates, bit for bit, as ``feed`` of the columns, message by message; a
    message going back in time is refused alike and changes nothing."""
    from armtrack.estimator.orientation.qcf import QuaternionComplementaryFilter
    from armtrack.estimator.orientation.qcf_kernel import COMPILED

    compiled_calls = []
    append_rows = QuaternionComplementaryFilter.append_rows
    monkeypatch.setattr(QuaternionComplementaryFilter, "append_rows",
                        lambda self, *args: compiled_calls.append(1) or append_rows(self, *args))
    rec = simulate(SimulationConfig(exercise="elbow_flexion", seed=5, nine_axis=nine_axis,
                                    jitter_s=0.001)).recording
    config = PipelineConfig(side=rec.side, lengths=rec.segment_lengths(),
                            sensors=tuple(rec.sensors))
    by_columns, by_rows = Pipeline(config), Pipeline(config)
    for pipeline in (by_columns, by_rows):
        for p in rec.calibration:
            pipeline.add_mark(Mark(p.start, p.name))
            pipeline.add_mark(Mark(p.end, f"end:{p.name}"))
    parts: dict[str, list] = {"columns": [], "rows": []}
    n = min(len(s.t) for s in rec.sensors.values())
    for a in range(0, n, 10):
        for name, s in rec.sensors.items():
            b = min(a + 10, n)
            by_columns.feed(name, s.t[a:b], s.acc[a:b], s.gyr[a:b],
                            None if s.mag is None else s.mag[a:b])
            by_rows.feed_rows(name, stream_rows(s, a, b))
        if a == 3000:  # a message from the past: refused by both, nothing changed
            s = rec.sensors["hand"]
            with pytest.raises(InvalidArgument, match="t goes backwards") as by_col_error:
                by_columns.feed("hand", s.t[a - 20:a - 10], s.acc[a - 20:a - 10],
                                s.gyr[a - 20:a - 10],
                                None if s.mag is None else s.mag[a - 20:a - 10])
            with pytest.raises(InvalidArgument, match="t goes backwards") as by_row_error:
                by_rows.feed_rows("hand", stream_rows(s, a - 20, a - 10))
            assert str(by_col_error.value) == str(by_row_error.value)
        parts["columns"].append(by_columns.poll())
        parts["rows"].append(by_rows.poll())
    estimated = sum(len(p) for p in parts["rows"])
    assert estimated > 0.9 * n
    assert len(compiled_calls) >= 3 * (n // 10), "feed_rows did not take the compiled path"
    assert COMPILED
    for column_part, row_part in zip(parts["columns"], parts["rows"], strict=True):
        assert column_part.t.tobytes() == row_part.t.tobytes()
        for k in REPORTED_ANGLES:
            assert column_part.angles[k].tobytes() == row_part.angles[k].tobytes(), k
        for p in column_part.positions:
            assert column_part.positions[p].tobytes() == row_part.positions[p].tobytes(), p
    print(f"{estimated} estimates of {n} samples, bit-identical ({'9' if nine_axis else '6'}-axis)")


# --- a remembered gyroscope bias (issue 18) -----------------------------------------------

ARM_ANGLES = ("elbow_flexion", "forearm_pronation", "wrist_flexion", "wrist_deviation")


def swaying_six_axis(seed: int):
    """A 6-axis kit on a patient whose trunk sways 8° at 0.15 Hz from the first sample, so
    no sensor is ever still (not even in the poses) and no rest teaches a bias; the true
    biases (from the same session simulated without them) and a remembered one per sensor,
    the truth off by a MEMS bias's day-to-day change (1 mrad/s an axis)."""
    from dataclasses import replace
    config = SimulationConfig(exercise="elbow_wrist", seed=seed, nine_axis=False,
                              trunk_sway=(8.0, 0.15))
    sim = simulate(config)
    unbiased = simulate(replace(config, gyro_bias_max=0.0)).recording.sensors
    true = {s: np.mean(st.gyr - unbiased[s].gyr, axis=0)
            for s, st in sim.recording.sensors.items()}
    rng = np.random.default_rng(seed)
    return sim, true, {s: b + rng.normal(0.0, 1e-3, 3) for s, b in true.items()}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_remembered_bias_holds_a_never_resting_kit_at_the_bar(seed):
    """The elbow and wrist angles (the arm's sensors' relative orientations: the trunk's sway
    does not enter them) against the truth, from no prior and from the kit's remembered
    biases; the learnt biases say nothing was learnt (none is remembered as if it were).
    Cold, the worst angle was 10.77 / 4.38 / 22.15° (seeds 0–2) until qcf's tilt windows
    learnt the bias in motion as the sensors turn: 1.43 / 0.91 / 6.19°, and 0.77 / 0.78 /
    2.04° since the elbow follows its sensors' heading drift (``constraints``), so the
    memory is what holds seed 2 at the bar, and it makes the arm's angles better on the
    whole on every seed (remembered: 0.86 / 1.43 / 0.74 → 0.83 / 0.90 / 0.73°; the prior is
    the truth ± 1 mrad/s)."""
    from armtrack.estimator.pipeline import run_recording
    sim, _, prior = swaying_six_axis(seed)
    rmse = {}
    for name, priors in (("cold", None), ("remembered", prior)):
        pipeline = run_recording(sim.recording, gyr_bias_priors=priors)
        estimates = pipeline.finish()
        m = estimates.t >= SCORED_FROM_S
        truth = sim_truth_deg(sim)
        rmse[name] = {k: float(np.sqrt(np.mean((np.rad2deg(estimates.angles[k][m]) - np.interp(
            estimates.t[m], sim.truth.t, truth[k])) ** 2))) for k in ARM_ANGLES}
        learnt = pipeline.learnt_biases()
        assert set(learnt) == set(sim.recording.sensors)
        assert all(v.learnt == "none" and not v.remembered for v in learnt.values())
        assert all(v.prior == (priors is not None) for v in learnt.values())
    print(f"seed {seed}, 6-axis, trunk swaying from the first sample: " + "; ".join(
        f"{k} {rmse['cold'][k]:.2f} → {rmse['remembered'][k]:.2f}°" for k in ARM_ANGLES))
    assert max(rmse["remembered"].values()) <= ANGLE_BAR_DEG[False]
    assert np.mean(list(rmse["remembered"].values())) < np.mean(list(rmse["cold"].values()))


def test_remembered_biases_streamed_in_chunks_equal_batch():
    from armtrack.estimator.pipeline import Estimates
    sim, _, prior = swaying_six_axis(0)
    batch, _ = estimate_recording(sim.recording, gyr_bias_priors=prior)
    stream = Estimates.concatenate(feed_in_chunks(sim.recording, np.random.default_rng(3),
                                                  gyr_bias_priors=prior))
    np.testing.assert_array_equal(stream.t, batch.t)
    for k in REPORTED_ANGLES:
        np.testing.assert_allclose(stream.angles[k], batch.angles[k], atol=1e-9, rtol=0)


def test_a_bad_remembered_bias_is_named_and_another_filter_refuses_one():
    config = PipelineConfig(side="right", lengths=SegmentLengths.from_height(1.75),
                            sensors=("forearm",))
    with pytest.raises(InvalidArgument, match="3 numbers"):
        Pipeline(config, gyr_bias_priors={"forearm": (0.0, 0.1)})
    with pytest.raises(InvalidArgument, match=r"within ±0\.2 rad/s"):
        Pipeline(config, gyr_bias_priors={"forearm": (0.0, 0.3, 0.0)})
    with pytest.raises(InvalidArgument, match="cannot start from a remembered"):
        Pipeline(PipelineConfig(side="right", lengths=SegmentLengths.from_height(1.75),
                                sensors=("forearm",), filter="ekf"),
                 gyr_bias_priors={"forearm": (0.0, 0.0, 0.0)})
    # a sensor the session does not wear is ignored (the kit's other sensors)
    Pipeline(config, gyr_bias_priors={"hand": (0.0, 0.0, 0.0)})
