"""When calibration becomes final (spec/kinematics.md, "Estimates"), from headers or marks."""

import numpy as np
import pytest
from armtrack.estimator.calibration import CalibrationPlan, poses_from_marks
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, estimate_recording
from armtrack.estimator.recording import Mark, Pose
from armtrack.estimator.simulation import SimulationConfig, simulate


def test_final_at_the_end_of_the_t_pose():
    plan = CalibrationPlan.from_poses([Pose("npose", 0.5, 3.0), Pose("tpose", 5.5, 8.0)])
    assert plan.method == "two-pose" and plan.final_time(0.0) == 8.0


def test_final_five_seconds_after_an_n_pose_with_no_t_pose_begun():
    plan = CalibrationPlan.from_poses([Pose("npose", 0.5, 3.0)])
    assert plan.method == "n-pose" and plan.final_time(0.0) == 8.0
    # a T-pose that begins later than that is not waited for
    late = CalibrationPlan.from_poses([Pose("npose", 0.5, 3.0), Pose("tpose", 9.0, 12.0)])
    assert late.tpose is None and late.final_time(0.0) == 8.0


def test_final_sixty_seconds_after_the_first_sample_without_poses():
    plan = CalibrationPlan.from_poses([])
    assert plan.method == "default" and plan.final_time(2.5) == 62.5


def test_marks_delimit_the_same_poses_as_the_header():
    marks = [Mark(0.5, "npose"), Mark(3.0, "end:npose"), Mark(4.0, "exercise:reach"),
             Mark(5.5, "tpose"), Mark(8.0, "end:tpose"), Mark(9.0, "tpose")]  # last: open
    assert poses_from_marks(marks) == [Pose("npose", 0.5, 3.0), Pose("tpose", 5.5, 8.0)]


@pytest.mark.parametrize("poses, final_s", [
    ((Pose("npose", 0.5, 3.0),), 8.0),
    ((), 60.0),
])
def test_stream_gives_nothing_until_final_then_everything_from_the_first_sample(poses, final_s):
    sim = simulate(SimulationConfig(exercise="reach", seed=41, tail_s=40.0))
    recording = sim.recording
    config = PipelineConfig(side="right", lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors))
    pipeline = Pipeline(config, poses=poses)
    for stop in np.arange(1.0, recording.duration + 1.0, 1.0):
        for name, s in recording.sensors.items():
            m = (s.t >= stop - 1.0) & (s.t < stop)
            pipeline.feed(name, s.t[m], s.acc[m], s.gyr[m], s.mag[m])
        out = pipeline.poll()
        if stop <= final_s:
            assert len(out) == 0, f"estimates at {stop} s before calibration was final"
        elif len(out):
            assert out.t[0] == recording.sensors["upper_arm"].t[0]
            break
    else:
        pytest.fail("no estimate after calibration became final")


def test_n_pose_only_with_the_default_long_axis_mounting():
    """The N-pose gives the tilt, the default mounting the turn about the long axis: with
    sensors mounted as assumed about that axis, the angles meet the bar."""
    sim = simulate(SimulationConfig(exercise="drinking", seed=42, mount_axial_deg=0.0))
    from armtrack.estimator.recording import Recording

    recording = Recording(side="right", sensors=sim.recording.sensors, height_m=1.75,
                          calibration=(Pose("npose", 0.5, 3.0),))
    estimates, calibration = estimate_recording(recording)
    assert calibration.method == "n-pose"
    m = estimates.t >= 10.5
    worst = max(float(np.sqrt(np.mean((estimates.angles[k][m] - np.interp(
        estimates.t[m], sim.truth.t, sim.truth.angles[k])) ** 2))) for k in estimates.angles)
    print(f"N-pose only, default long-axis mounting: worst angle RMSE {np.rad2deg(worst):.2f}°")
    assert np.rad2deg(worst) <= 1.0
