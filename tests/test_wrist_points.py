"""The γ elbow in use (docs/extensions/points.md): wrist points in recordings, refused
whole when malformed, and the pipeline's elbow from an upper-arm IMU plus the points,
against the simulation's truth beside the IMU-only pipeline on the same session."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument, InvalidRecording
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, run_recording
from armtrack.estimator.recording import format_recording, parse_recording, write_recording
from armtrack.estimator.recording.points import PointsFrame, PointStream
from armtrack.estimator.simulation import SimulationConfig, simulate

SCORED_FROM_S = 12.0  # after the calibration poses


def _score(sim, pipeline, estimates):
    """Elbow flexion RMSE [deg] and elbow position RMSE [m] over t ≥ SCORED_FROM_S where
    the wrist had a point, and the shares of samples held (γ ill-conditioned) and
    without a point."""
    truth = sim.truth
    scored = estimates.t >= SCORED_FROM_S
    held = none = np.zeros(len(estimates.t), bool)
    if pipeline.gamma is not None:
        held, none = pipeline.gamma.flags()
    keep = scored & ~none

    def at(x):
        return np.interp(estimates.t, truth.t, x)

    flexion = np.rad2deg(estimates.angles["elbow_flexion"] - at(truth.angles["elbow_flexion"]))
    elbow = np.column_stack([at(truth.positions["elbow"][:, k]) for k in range(3)])
    distance = np.linalg.norm(estimates.positions["elbow"] - elbow, axis=1)
    return (float(np.sqrt(np.mean(flexion[keep] ** 2))),
            float(np.sqrt(np.mean(distance[keep] ** 2))),
            float(held[scored].mean()), float(none[scored].mean()))


def _session(exercise, side, height, source, seed, lengths=None, **extra):
    config = SimulationConfig(exercise=exercise, side=side, height_m=height, seed=seed,
                              sensors=("upper_arm",), nine_axis=False, wrist_points=source,
                              **extra)
    return config, simulate(config, lengths=lengths)


BODIES = [  # (side, height, measured lengths unlike the height formula, or None)
    ("right", 1.58, None),
    ("left", 1.92, None),
    ("right", 1.75, SegmentLengths(clavicle=0.20, upper_arm=0.36, forearm=0.24, hand=0.18)),
    ("left", 1.66, SegmentLengths(clavicle=0.22, upper_arm=0.29, forearm=0.28, hand=0.19)),
]


@pytest.mark.parametrize("exercise", ["reach", "elbow_flexion"])
@pytest.mark.parametrize("side,height,lengths", BODIES)
def test_gamma_elbow_with_robot_points_meets_the_bar(exercise, side, height, lengths):
    """A robot's wrist (100 Hz, 0.5 mm) and a 6-axis upper-arm IMU alone: elbow position
    within 1 cm and flexion within 2° RMSE of truth; printed beside a camera's points and
    the IMU-only pipeline (upper arm, forearm, hand) on the same motion."""
    seed = int(height * 100)
    config, sim = _session(exercise, side, height, "robot", seed, lengths)
    if lengths is not None:  # measured lengths travel in the header
        assert parse_recording(format_recording(sim.recording)).lengths == lengths
    pipeline = run_recording(sim.recording)
    estimates = pipeline.finish()
    assert pipeline.elbow_source == "points"
    flexion, position, held, none = _score(sim, pipeline, estimates)

    _, camera = _session(exercise, side, height, "camera", seed, lengths)
    camera_pipeline = run_recording(camera.recording)
    c_flexion, c_position, c_held, c_none = _score(camera, camera_pipeline,
                                                   camera_pipeline.finish())
    imu = simulate(replace(config, sensors=("upper_arm", "forearm", "hand"), wrist_points=None),
                   lengths=lengths)
    imu_pipeline = run_recording(imu.recording)
    i_flexion, i_position, _, _ = _score(imu, imu_pipeline, imu_pipeline.finish())
    print(f"\n{exercise} {side} {height} m{' measured lengths' if lengths else ''}: "
          f"robot flexion {flexion:.2f}° elbow {position * 100:.2f} cm (γ held {held:.0%}); "
          f"camera {c_flexion:.2f}° {c_position * 100:.2f} cm (held {c_held:.0%}, no point "
          f"{c_none:.0%}); IMU-only 3 sensors {i_flexion:.2f}° {i_position * 100:.2f} cm")
    assert none == 0.0
    assert flexion <= 2.0 and position <= 0.01
    assert np.isfinite([c_flexion, c_position]).all() and c_none > 0.0  # dropouts happen


def test_points_hold_the_heading_of_a_drifting_six_axis_upper_arm():
    """Where the IMUs alone drift (6-axis, 3 minutes of reaching, a gyroscope bias up to
    0.02 rad/s that walks, no rest to learn it), the wrist points keep the upper arm's
    heading: elbow and shoulder stay right. Two seeds."""
    errors = replace(SimulationConfig().errors, gyro_bias_walk=3e-4)
    for seed in (11, 12):
        config = SimulationConfig(exercise="reach", repetitions=40, rate_hz=60.0, seed=seed,
                                  sensors=("upper_arm", "forearm"), nine_axis=False,
                                  gyro_bias_max=0.02, errors=errors, wrist_points="robot")
        sim = simulate(config)
        with_points = run_recording(sim.recording)
        p_estimates = with_points.finish()
        p_flexion, p_position, _, _ = _score(sim, with_points, p_estimates)
        imu_only = run_recording(replace(sim.recording, points={}, points_frame=None))
        i_estimates = imu_only.finish()
        i_flexion, i_position, _, _ = _score(sim, imu_only, i_estimates)

        def rmse(estimates, name, sim=sim):
            truth = np.interp(estimates.t, sim.truth.t, sim.truth.angles[name])
            keep = estimates.t >= SCORED_FROM_S
            error = (estimates.angles[name] - truth)[keep]
            return float(np.rad2deg(np.sqrt(np.mean(error ** 2))))

        p_abd, i_abd = (rmse(e, "shoulder_abduction") for e in (p_estimates, i_estimates))
        d = with_points.gamma.stats.disagreement_rms_deg
        print(f"\nseed {seed}, {sim.truth.t[-1]:.0f} s of 6-axis reaching, drifting bias: elbow "
              f"{p_position * 100:.2f} cm with points, {i_position * 100:.2f} cm IMU only; "
              f"shoulder abduction {p_abd:.2f}° / {i_abd:.2f}°; elbow flexion "
              f"{p_flexion:.2f}° / {i_flexion:.2f}° (from the forearm IMU; the points' "
              f"flexion differs by {d:.2f}° RMS)")
        assert with_points.elbow_source == "imu" and d is not None and d < 2.0
        assert p_position <= 0.01 and p_position < i_position
        assert p_abd <= 1.0


def test_batch_equals_any_chunking_of_samples_and_points():
    """Fed in chunks, interleaved, the pipeline gives the batch's numbers bit for bit."""
    _, sim = _session("reach", "right", 1.75, "camera", 5)
    rec = sim.recording
    batch = run_recording(rec).finish()
    config = PipelineConfig(side=rec.side, lengths=rec.segment_lengths(),
                            sensors=tuple(rec.sensors))
    pipeline = Pipeline(config, poses=rec.calibration, points_frame=rec.points_frame)
    imu, wrist = rec.sensors["upper_arm"], rec.points["wrist"]
    rng = np.random.default_rng(0)
    i = j = 0
    parts = []
    while i < len(imu) or j < len(wrist):
        n = int(rng.integers(1, 40))
        if i < len(imu) and (j >= len(wrist) or imu.t[min(i + n, len(imu) - 1)]
                             <= wrist.t[j] + 0.5):
            pipeline.feed("upper_arm", imu.t[i:i + n], imu.acc[i:i + n], imu.gyr[i:i + n])
            i += n
        else:
            pipeline.feed_points("wrist", wrist.t[j:j + n], wrist.p[j:j + n])
            j += n
        parts.append(pipeline.poll())
    parts.append(pipeline.finish())
    t = np.concatenate([p.t for p in parts])
    flexion = np.concatenate([p.angles["elbow_flexion"] for p in parts])
    np.testing.assert_array_equal(t, batch.t)
    np.testing.assert_array_equal(flexion, batch.angles["elbow_flexion"])


def test_an_error_in_the_shoulder_shows_in_the_elbow():
    """How a wrong set-up shoulder shows: 1 cm off moves the elbow by about 1 cm and the
    flexion by a few degrees (printed: the operator's guide quotes it)."""
    _, sim = _session("reach", "right", 1.75, "robot", 9)
    base = run_recording(sim.recording)
    flexion0, position0, _, _ = _score(sim, base, base.finish())
    for direction in np.eye(3):
        frame = sim.recording.points_frame
        moved = replace(frame, shoulder_m=tuple(np.add(frame.shoulder_m, 0.01 * direction)))
        pipeline = run_recording(replace(sim.recording, points_frame=moved))
        flexion, position, _, _ = _score(sim, pipeline, pipeline.finish())
        print(f"\nshoulder 1 cm off along base {'xyz'[int(np.argmax(direction))]}: elbow "
              f"{position * 100:.2f} cm (exact: {position0 * 100:.2f}), flexion {flexion:.2f}° "
              f"(exact: {flexion0:.2f}°)")
        assert position < 0.02


# -- the file format --------------------------------------------------------------------------
def test_points_round_trip_to_the_same_numbers(tmp_path):
    _, sim = _session("reach", "left", 1.7, "camera", 2)
    path = tmp_path / "rec.csv"
    write_recording(sim.recording, path)
    text = path.read_text()
    assert text.startswith("# armtrack-recording: 2\n") and "\nt,point,x,y,z\n" in text
    back = parse_recording(path.read_bytes())
    assert back.points_frame == sim.recording.points_frame
    for name in ("t", "p"):
        assert np.array_equal(getattr(back.points["wrist"], name),
                              getattr(sim.recording.points["wrist"], name))
    for sensor, stream in sim.recording.sensors.items():
        assert np.array_equal(back.sensors[sensor].acc, stream.acc)
    assert "points_frame" not in back.metadata
    # a recording without points stays version 1, byte for byte what it was
    plain = replace(sim.recording, points={}, points_frame=None)
    assert format_recording(plain).startswith(b"# armtrack-recording: 1\n")
    assert b"t,point" not in format_recording(plain)


def test_a_thorax_frame_with_a_measured_shoulder_round_trips():
    _, sim = _session("elbow_flexion", "right", 1.75, "robot", 1)
    frame = PointsFrame("thorax", shoulder_m=(0.01, -0.02, 0.2))
    rec = replace(sim.recording, points_frame=frame)
    assert parse_recording(format_recording(rec)).points_frame == frame


GOOD = ("# armtrack-recording: 2\n# side: right\n# height_m: 1.75\n# points_frame: thorax\n"
        "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
        "0,upper_arm,0,9.81,0,0,0,0,,,\n0.01,upper_arm,0,9.81,0,0,0,0,,,\n"
        "t,point,x,y,z\n0,wrist,0.1,-0.5,0.2\n0.02,wrist,0.1,-0.5,0.2\n")


def test_the_good_example_reads():
    rec = parse_recording(GOOD.encode())
    assert rec.points["wrist"].p.shape == (2, 3) and rec.points_frame.kind == "thorax"
    assert len(rec.sensors["upper_arm"]) == 2


@pytest.mark.parametrize("change,line,words", [
    (("0.02,wrist,0.1,-0.5,0.2\n", "0.02,wrist,0.1,-0.5\n"), 10, "expected 5 fields"),
    (("0.02,wrist,", "0.02,elbow,"), 10, "unknown point 'elbow'"),
    (("0.02,wrist,0.1,", "0.02,wrist,nan,"), 10, "not finite"),
    (("0.02,wrist,0.1,", "0.02,wrist,11,"), 10, "at most 10 m"),
    (("0.02,wrist,", "-1,wrist,"), 10, "t goes backwards for point wrist"),
    (("0.02,wrist,0.1,-0.5,0.2\n", "0.02,wrist,0.1,-0.5,0.2\n\n0.03,wrist,0,0,0\n"), 11,
     "blank line"),
    (("# points_frame: thorax\n", ""), 7, "needs the header 'points_frame'"),
    (("# points_frame: thorax\n", "# points_frame: base\n"), 4, "thorax's yaw"),
    (("# points_frame: thorax\n", "# points_frame: camera\n"), 4, "thorax or base"),
    (("# points_frame: thorax\n", "# points_frame: thorax\n# points_shoulder_m: 1 2\n"), 5,
     "points_shoulder_m must be 'X Y Z'"),
    (("t,point,x,y,z\n0,wrist,0.1,-0.5,0.2\n0.02,wrist,0.1,-0.5,0.2\n", "t,point,x,y,z\n"), 8,
     "no point rows"),
])
def test_malformed_points_are_refused_whole_naming_the_line(change, line, words):
    text = GOOD.replace(*change)
    assert text != GOOD
    with pytest.raises(InvalidRecording) as caught:
        parse_recording(text.encode())
    assert caught.value.line == line and words in str(caught.value), str(caught.value)


def test_a_version_1_file_cannot_carry_points():
    """An old reader's version: the points section is not a v1 row (refused, not skipped)."""
    with pytest.raises(InvalidRecording) as caught:
        parse_recording(GOOD.replace("recording: 2", "recording: 1").encode())
    assert caught.value.line == 8 and "armtrack-recording: 2" in str(caught.value)


def test_points_need_their_frame_and_known_names():
    _, sim = _session("elbow_flexion", "right", 1.75, "robot", 1)
    stream = sim.recording.points["wrist"]
    with pytest.raises(InvalidArgument, match="points_frame"):
        replace(sim.recording, points_frame=None)
    with pytest.raises(InvalidArgument, match="unknown point"):
        replace(sim.recording, points={"elbow": stream})
    with pytest.raises(InvalidArgument, match="yaw"):
        PointsFrame("base", shoulder_m=(0, 0, 1))
    assert isinstance(stream, PointStream)
