"""A kit whose gyroscope lags its accelerometer (``gyro_delay_s``,
``docs/extensions/gyro-delay.md``): the simulator stamps the gyroscope late, ``qcf``
integrates a declared delay away, and the declaration reaches the filters from a
recording's header through the pipeline; batch equals any chunking; bad values are
refused naming the field."""

import dataclasses
import math

import numpy as np
import pytest
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument, InvalidRecording
from armtrack.estimator.orientation import make_filter
from armtrack.estimator.pipeline import PipelineConfig, estimate_recording
from armtrack.estimator.recording import format_recording, parse_recording
from armtrack.estimator.simulation import (
    ImuErrors,
    Motion,
    Profile,
    SimulationConfig,
    Sine,
    Stance,
    body_motion,
    default_mount,
    simulate,
    synthesize_imu,
)
from orientation_helpers import angle_error_deg, rms, stream, tilt_error_deg

#: BROAD's gyroscope lags its accelerometer by 0.65 samples (bench/timing.py); at 100 Hz:
DELAY_S = 0.0065
SCORED_FROM_S = 10.0


def fast_take(seed: int, delay_s: float, nine_axis: bool):
    """The forearm sensor through a minute of brisk arm motion (elbow, shoulder, forearm
    sines at 0.5–0.9 Hz, rates up to 4 rad/s), realistic noise and bias; its gyroscope
    stamped ``delay_s`` late."""
    lengths = SegmentLengths.from_height(1.75)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 0.01)
    phase = rng.uniform(0.0, 2 * math.pi, 4)
    motion = Motion(joints={
        "elbow_flexion": Profile(offset=1.0, sines=(Sine(0.6, 0.8, phase[0]),)),
        "shoulder_flexion": Profile(offset=0.5, sines=(Sine(0.3, 0.5, phase[1]),)),
        "shoulder_rotation": Profile(sines=(Sine(0.4, 0.6, phase[2]),)),
        "pronation": Profile(sines=(Sine(0.6, 0.9, phase[3]),))})
    stance = Stance(heading=0.5)
    body = body_motion(motion, "right", lengths, t, stance)
    late = body_motion(motion, "right", lengths, t - delay_s, stance) if delay_s else None
    return synthesize_imu(body, "forearm", default_mount("forearm", "right", lengths),
                          nine_axis=nine_axis, rng=rng, gyro_body=late,
                          errors=ImuErrors(gyro_noise=0.004, acc_noise=0.04, mag_noise=0.4,
                                           gyro_bias=(0.005, -0.004, 0.003)))


def scored(take, declared_s: float) -> tuple[float, float]:
    """Tilt and whole-orientation RMSE [deg] of ``qcf`` told ``declared_s``."""
    q = make_filter("qcf", gyro_delay_s=declared_s).update_batch(
        take.t, take.acc, take.gyr, take.mag).q
    k = take.t >= SCORED_FROM_S
    R = take.R_world_sensor[k]
    return rms(tilt_error_deg(R, q[k])), rms(angle_error_deg(R, q[k]))


@pytest.mark.parametrize("nine_axis", [False, True], ids=["6D", "9D"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_late_gyroscope_declared_scores_as_one_in_step(seed, nine_axis):
    in_step = scored(fast_take(seed, 0.0, nine_axis), 0.0)
    late = fast_take(seed, DELAY_S, nine_axis)
    undeclared, declared = scored(late, 0.0), scored(late, DELAY_S)
    # (6D: the whole orientation's heading is arbitrary, only the tilt is scored)
    print(f"seed {seed} {'9D' if nine_axis else '6D'} tilt / whole RMSE [deg]: in step "
          f"{in_step[0]:.3f} / {in_step[1]:.3f}, 0.65-sample late gyroscope "
          f"{undeclared[0]:.3f} / {undeclared[1]:.3f}, declared {declared[0]:.3f} / "
          f"{declared[1]:.3f}")
    # the late gyroscope costs tilt; declared, it is back to the in-step figure
    assert undeclared[0] > in_step[0] + 0.3
    assert abs(declared[0] - in_step[0]) < 0.05
    assert declared[0] < 1.0 and in_step[0] < 1.0
    if nine_axis:  # heading too: within 0.15° of in step (the magnetometer's own noise)
        assert abs(declared[1] - in_step[1]) < 0.15


def test_the_delay_is_the_same_in_any_chunks_and_zero_changes_nothing():
    take = fast_take(1, DELAY_S, True)
    batch = make_filter("qcf", gyro_delay_s=DELAY_S).update_batch(
        take.t, take.acc, take.gyr, take.mag)
    for seed in (0, 1):
        chunked = stream(lambda: make_filter("qcf", gyro_delay_s=DELAY_S), take,
                         np.random.default_rng(seed))
        np.testing.assert_array_equal(chunked.q, batch.q)
        np.testing.assert_array_equal(chunked.gyr_bias, batch.gyr_bias)
    python = make_filter("qcf", gyro_delay_s=DELAY_S)
    python.compiled = False
    np.testing.assert_allclose(python.update_batch(take.t, take.acc, take.gyr, take.mag).q,
                               batch.q, atol=1e-9)
    plain = make_filter("qcf").update_batch(take.t, take.acc, take.gyr, take.mag)
    zero = make_filter("qcf", gyro_delay_s=0.0).update_batch(take.t, take.acc, take.gyr, take.mag)
    np.testing.assert_array_equal(zero.q, plain.q)
    assert not np.array_equal(batch.q, plain.q)


@pytest.mark.parametrize("bad", [-0.001, 0.051, float("nan"), float("inf"), "2 ms", True, None])
def test_a_bad_delay_is_refused_naming_the_field(bad):
    with pytest.raises(InvalidArgument, match="gyro_delay_s"):
        make_filter("qcf", gyro_delay_s=bad)
    with pytest.raises(InvalidArgument, match="gyro_delay_s"):
        PipelineConfig(side="right", lengths=SegmentLengths.from_height(1.75),
                       sensors=("forearm",), gyro_delay_s=bad)


def test_filters_without_the_delay_refuse_one_and_take_zero():
    with pytest.raises(InvalidArgument, match="gyro_delay_s"):
        make_filter("ekf", gyro_delay_s=DELAY_S)
    make_filter("ekf", gyro_delay_s=0.0)


def kit(seed: int, delay_s: float, declare: bool):
    return simulate(SimulationConfig(exercise="elbow_flexion", seed=seed, nine_axis=False,
                                     gyro_delay_s=delay_s, declare_gyro_delay=declare))


def test_a_simulated_kit_declares_its_delay_in_the_header_and_estimation_uses_it():
    """The whole pipeline, from a written and read-back recording: the declared delay
    reaches every sensor's filter and gives the in-step kit's angles back."""
    def elbow_rmse(simulation):
        data = format_recording(simulation.recording)
        estimates, _ = estimate_recording(parse_recording(data))
        truth = simulation.truth
        est = np.interp(truth.t, estimates.t, estimates.angles["elbow_flexion"])
        k = truth.t >= 10.5
        return rms(np.rad2deg(est[k] - truth.angles["elbow_flexion"][k])), data
    in_step, _ = elbow_rmse(kit(2, 0.0, False))
    undeclared, plain = elbow_rmse(kit(2, DELAY_S, False))
    declared, data = elbow_rmse(kit(2, DELAY_S, True))
    print(f"elbow flexion RMSE [deg], 6-axis kit: in step {in_step:.3f}, late gyroscope "
          f"{undeclared:.3f}, declared {declared:.3f}")
    assert b"# gyro_delay_s: 0.0065\n" in data and b"gyro_delay_s" not in plain
    assert parse_recording(data).gyro_delay_s == DELAY_S
    assert abs(declared - in_step) < 0.5 * abs(undeclared - in_step) + 0.01
    assert declared < 2.0


@pytest.mark.parametrize("value", ["-0.001", "0.2", "nan", "2ms", ""])
def test_a_bad_header_is_refused_naming_the_line(value):
    data = format_recording(kit(1, 0.0, False).recording)
    data = data.replace(b"# rate_hz:", f"# gyro_delay_s: {value}\n# rate_hz:".encode(), 1)
    with pytest.raises(InvalidRecording, match="gyro_delay_s") as caught:
        parse_recording(data)
    assert caught.value.line == 5


def test_a_recording_object_refuses_a_bad_declared_delay():
    recording = kit(1, 0.0, False).recording
    with pytest.raises(InvalidArgument, match="gyro_delay_s"):
        dataclasses.replace(recording, metadata={"gyro_delay_s": "0.06"})


def test_armtrack_estimate_uses_the_files_declared_delay(tmp_path):
    """``armtrack estimate`` (the command, in its own process) of a file with the header
    gives the pipeline's numbers with the delay; without the header, those without."""
    from server_support import armtrack
    simulation = kit(2, DELAY_S, True)
    data = format_recording(simulation.recording)
    paths = {"declared": tmp_path / "declared.csv", "plain": tmp_path / "plain.csv"}
    paths["declared"].write_bytes(data)
    paths["plain"].write_bytes(data.replace(b"# gyro_delay_s: 0.0065\n", b""))
    for name, path in paths.items():
        out = tmp_path / f"{name}.angles.csv"
        done = armtrack("estimate", str(path), "-o", str(out))
        assert done.returncode == 0, done.stderr
        table = np.genfromtxt(out, delimiter=",", names=True)
        expected, _ = estimate_recording(parse_recording(path.read_bytes()))
        np.testing.assert_allclose(table["elbow_flexion"],
                                   np.rad2deg(expected.angles["elbow_flexion"]), atol=6e-5)
        if name == "declared":
            declared = table["elbow_flexion"]
    assert np.max(np.abs(declared - table["elbow_flexion"])) > 0.1
    done = armtrack("estimate", str(paths["declared"]), "--filter", "ekf",
                    "-o", str(tmp_path / "ekf.csv"))
    assert done.returncode == 2 and "gyro_delay_s" in done.stderr, done.stderr
