"""The simulator's physics against independent references: finite differences of its own
positions and orientations, gyroscope integration, gravity at rest, the earth's field."""

import numpy as np
import pytest
from armtrack.estimator.arm import ANGLE_NAMES, forward_kinematics, joint_angles
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.recording import format_recording, parse_recording
from armtrack.estimator.simulation import (
    EXERCISES,
    ImuErrors,
    Motion,
    Profile,
    Ramp,
    SimulationConfig,
    Sine,
    body_motion,
    default_mount,
    exercise_motion,
    simulate,
    synthesize_imu,
)
from armtrack.estimator.simulation.imu import EARTH_FIELD_UT
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

LENGTHS = SegmentLengths.from_height(1.70)
NOISELESS = ImuErrors()


def busy_motion(seed=0):
    """Every joint and the trunk moving at once: ramps and sines."""
    rng = np.random.default_rng(seed)

    def profile():
        ramps = tuple(Ramp(rng.uniform(0.5, 2.5), rng.uniform(-1, 1), rng.uniform(0.2, 0.8))
                      for _ in range(3))
        return Profile(rng.uniform(-0.3, 0.3), ramps, (Sine(0.1, rng.uniform(0.2, 2), 1.0),))

    trunk = ("trunk_heading", "trunk_flexion", "trunk_lateral", "trunk_rotation")
    return Motion({k: profile() for k in ANGLE_NAMES}, {k: profile() for k in trunk})


def test_ramp_is_the_thesis_gaussian_pulse():
    """Thesis App. B.2: ω = A·2/√(2π)·exp(−2 (t − t0)²) is a ramp of A with σ = 0.5 s."""
    t = np.linspace(0, 10, 2001)
    A, t0 = np.pi / 6, 2.5
    q, dq, ddq = Profile(ramps=(Ramp(t0, A, 0.5),)).evaluate(t)
    np.testing.assert_allclose(dq, A * 2 / np.sqrt(2 * np.pi) * np.exp(-2 * (t - t0) ** 2),
                               atol=1e-15)
    assert q[0] == pytest.approx(0, abs=1e-6) and q[-1] == pytest.approx(A, abs=1e-12)
    np.testing.assert_allclose(np.gradient(q, t), dq, atol=2e-4)
    np.testing.assert_allclose(np.gradient(dq, t), ddq, atol=2e-3)


@pytest.mark.parametrize("side", ["right", "left"])
def test_body_motion_matches_forward_kinematics_and_finite_differences(side):
    motion = busy_motion()
    t = np.linspace(0, 6, 30001)
    h = t[1] - t[0]
    body = body_motion(motion, side, LENGTHS, t)
    angles = {k: motion.joints[k].evaluate(t)[0] for k in ANGLE_NAMES}
    pose = forward_kinematics(angles, side, LENGTHS)
    R_world_thorax = body.frames["thorax"].R
    for segment, R in pose.R_thorax.items():
        np.testing.assert_allclose(body.frames[segment].R, R_world_thorax @ R, atol=1e-14)
    notch = body.points["sternal_notch"].p
    for point, p in pose.p_thorax.items():
        np.testing.assert_allclose(body.points[point].p,
                                   notch + np.einsum("nij,nj->ni", R_world_thorax, p), atol=1e-14)
    worst_a = worst_w = 0.0
    for point in ("hand", "elbow", "sternal_notch"):
        numeric = np.gradient(np.gradient(body.points[point].p, h, axis=0), h, axis=0)
        worst_a = max(worst_a, np.abs(numeric - body.points[point].a)[10:-10].max())
    for segment in ("hand", "upper_arm", "thorax"):
        R = body.frames[segment].R
        W = np.swapaxes(R[1:-1], -1, -2) @ (R[2:] - R[:-2]) / (2 * h)
        numeric = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=-1)
        worst_w = max(worst_w, np.abs(numeric - body.frames[segment].omega[1:-1]).max())
    print(f"{side}: exact vs finite differences: acceleration {worst_a:.1e} m/s², "
          f"angular rate {worst_w:.1e} rad/s")
    assert worst_a < 1e-4 and worst_w < 1e-5


@pytest.mark.parametrize("sensor", ["trunk", "clavicle", "upper_arm", "forearm", "hand"])
def test_integrating_the_gyroscope_reproduces_the_orientation(sensor):
    """q̇ = ½ q ⊗ (0, ω) integrated by scipy's DOP853 (rtol 1e-11) from the simulator's
    noise-free gyroscope, evaluated wherever the integrator asks, over 3 s of busy motion."""
    motion = busy_motion(1)
    mount = default_mount(sensor, "right", LENGTHS)

    def imu_at(t):
        body = body_motion(motion, "right", LENGTHS, np.atleast_1d(t))
        return synthesize_imu(body, sensor, mount, errors=NOISELESS, nine_axis=False)

    def rate(t, q):
        wx, wy, wz = imu_at(t).gyr[0]
        w, x, y, z = q
        return 0.5 * np.array([-x * wx - y * wy - z * wz, w * wx + y * wz - z * wy,
                               w * wy - x * wz + z * wx, w * wz + x * wy - y * wx])

    q0 = Rotation.from_matrix(imu_at(0.0).R_world_sensor[0]).as_quat(scalar_first=True)
    solution = solve_ivp(rate, (0.0, 3.0), q0, method="DOP853", rtol=1e-11, atol=1e-12)
    R_end = Rotation.from_quat(solution.y[:, -1], scalar_first=True)
    R_true = Rotation.from_matrix(imu_at(3.0).R_world_sensor[0])
    error = np.rad2deg((R_end.inv() * R_true).magnitude())
    print(f"{sensor}: orientation from the integrated gyroscope after 3 s off by {error:.1e} deg")
    assert error < 1e-6


def test_at_rest_the_accelerometer_reads_gravity_and_the_magnetometer_the_earth():
    sim = simulate(SimulationConfig(exercise="elbow_flexion", errors=NOISELESS, gyro_bias_max=0,
                                    sensors=("trunk", "clavicle", "upper_arm", "forearm", "hand")))
    for name, stream in sim.recording.sensors.items():
        still = (stream.t > 0.5) & (stream.t < 2.0)  # the N-pose, far from the rise
        R_ws = sim.truth.R_world_sensor[name][still]
        up_in_sensor = R_ws[:, 2, :]  # world z in sensor axes
        np.testing.assert_allclose(stream.acc[still], 9.81 * up_in_sensor, atol=1e-9)
        np.testing.assert_allclose(stream.gyr[still], 0.0, atol=1e-9)
        np.testing.assert_allclose(stream.mag[still], np.einsum("nji,j->ni", R_ws, EARTH_FIELD_UT),
                                   atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(stream.mag[still], axis=1), 48.0, atol=1e-9)


@pytest.mark.parametrize("side", ["right", "left"])
def test_default_mounting_puts_sensor_axes_as_the_spec_says(side):
    """N-pose: arm sensors +Y up (proximal), +Z lateral; trunk +Z anterior; clavicle +Z lateral."""
    sim = simulate(SimulationConfig(side=side, errors=NOISELESS, gyro_bias_max=0,
                                    mount_axial_deg=0, mount_tilt_deg=0, heading_deg=0,
                                    sensors=("trunk", "clavicle", "upper_arm", "forearm", "hand")))
    lateral_world = np.array([0.0, -1.0 if side == "right" else 1.0, 0.0])  # facing +x
    for name, R in sim.truth.R_world_sensor.items():
        R0 = R[0]
        if name == "clavicle":
            np.testing.assert_allclose(R0[:, 2], lateral_world, atol=1e-12)
            np.testing.assert_allclose(R0[:, 1], [0, 0, 1], atol=1e-12)
        elif name == "trunk":
            np.testing.assert_allclose(R0[:, 1], [0, 0, 1], atol=1e-12)
            np.testing.assert_allclose(R0[:, 2], [1, 0, 0], atol=1e-12)
        else:
            np.testing.assert_allclose(R0[:, 1], [0, 0, 1], atol=1e-12)
            np.testing.assert_allclose(R0[:, 2], lateral_world, atol=1e-12)


@pytest.mark.parametrize("side", ["right", "left"])
def test_truth_angles_are_those_of_the_true_sensor_orientations(side):
    config = SimulationConfig(exercise="drinking", side=side, seed=4,
                              sensors=("trunk", "clavicle", "upper_arm", "forearm", "hand"))
    sim = simulate(config)
    segment_of = {"trunk": "thorax", "clavicle": "clavicle", "upper_arm": "upper_arm",
                  "forearm": "forearm", "hand": "hand"}
    R_world = {segment_of[s]: R @ sim.truth.mounts[s].R_segment_sensor.T
               for s, R in sim.truth.R_world_sensor.items()}
    stream_t = sim.recording.sensors["upper_arm"].t
    np.testing.assert_allclose(stream_t, sim.truth.t, atol=0)  # no jitter, nothing lost
    result = joint_angles(R_world, side)
    worst = max(np.abs(np.angle(np.exp(1j * (result.angles[k] - sim.truth.angles[k])))).max()
                for k in (*ANGLE_NAMES, "shoulder_elevation"))
    assert worst < 1e-9


def test_faults_jitter_lost_samples_six_axis_bias():
    config = SimulationConfig(exercise="abduction_120", rate_hz=50, nine_axis=False,
                              jitter_s=0.001, lost_fraction=0.02, seed=3)
    sim = simulate(config)
    for stream in sim.recording.sensors.values():
        assert stream.mag is None
        nominal = np.rint(stream.t * 50) / 50
        assert np.abs(stream.t - nominal).max() <= 0.001
        assert np.all(np.diff(stream.t) > 0)
        lost = 1 - len(stream) / len(sim.truth.t)
        assert 0.01 < lost < 0.03, lost
        still = (stream.t > 0.5) & (stream.t < 2.5)
        bias = stream.gyr[still].mean(axis=0)
        assert np.all(np.abs(bias) <= 0.012 + 0.002) and np.abs(bias).max() > 1e-3
    assert np.rad2deg(sim.truth.angles["shoulder_abduction"]).max() == pytest.approx(120, abs=0.1)


def test_magnet_near_the_hand_disturbs_the_hand_more_than_the_upper_arm():
    sim = simulate(SimulationConfig(exercise="reach", magnet_near_hand=True, errors=NOISELESS))
    excess = {}
    for name, stream in sim.recording.sensors.items():
        excess[name] = np.abs(np.linalg.norm(stream.mag, axis=1) - 48.0).max()
    print("largest field error (µT):", {k: round(v, 1) for k, v in excess.items()})
    assert excess["hand"] > 10.0 and excess["hand"] > 3 * excess["upper_arm"]


@pytest.mark.parametrize("exercise", sorted(EXERCISES))
def test_every_exercise_writes_a_recording_that_reads_back(exercise):
    sim = simulate(SimulationConfig(exercise=exercise, sensors=("upper_arm", "forearm")))
    back = parse_recording(format_recording(sim.recording))
    for name, stream in sim.recording.sensors.items():
        np.testing.assert_array_equal(back.sensors[name].acc, stream.acc)
        np.testing.assert_array_equal(back.sensors[name].t, stream.t)
    assert [p.name for p in back.calibration] == ["npose", "tpose"]
    motion = exercise_motion(exercise)
    assert sim.truth.t[-1] >= motion.end_time()


def test_a_longer_npose_moves_the_rest_of_the_session_later():
    """``npose_s``: the N-pose held that long from the start; the T-pose, its windows and
    the exercise come that much later (the 3-s default is the shared timeline)."""
    from armtrack.estimator.errors import InvalidArgument
    from armtrack.estimator.simulation import SimulationConfig, simulate

    short = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1, seed=1))
    long = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1, seed=1,
                                     npose_s=15.0))
    windows = [(p.name, p.start, p.end) for p in long.recording.calibration]
    print(windows)
    assert windows == [("npose", 0.5, 15.0), ("tpose", 17.5, 20.0)]
    assert [(p.start, p.end) for p in short.recording.calibration] == [(0.5, 3.0), (5.5, 8.0)]
    abduction = np.rad2deg(long.truth.angles["shoulder_abduction"])
    t = long.truth.t
    assert abs(abduction[t <= 15.0]).max() < 1.0
    assert abduction[(t >= 17.5) & (t <= 20.0)].min() > 89.0
    def first_rep(sim):
        return sim.truth.t[np.rad2deg(sim.truth.angles["elbow_flexion"]) > 10.0][0]
    assert first_rep(long) - first_rep(short) == pytest.approx(12.0, abs=0.02)
    with pytest.raises(InvalidArgument, match="npose_s must be within 1–600 s"):
        SimulationConfig(npose_s=0.5)
