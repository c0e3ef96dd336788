"""Joint angles from segment orientations: exact inverse, residuals, the shoulder singularity."""

import itertools

import numpy as np
import pytest
from armtrack.estimator.arm import (
    ANGLE_NAMES,
    REPORTED_ANGLES,
    JointAngleParams,
    JointAngleSolver,
    forward_kinematics,
    joint_angles,
)
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.rotations import elemental
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

LENGTHS = SegmentLengths.from_height(1.80)
DEG = np.pi / 180
#: Random angles well inside each joint's physiological range; abduction stays outside
#: the shoulder's singular zone so that every sample on its own has one answer.
LIMITS_DEG = {
    "clavicle_protraction": (-30, 30), "clavicle_elevation": (-15, 40),
    "shoulder_flexion": (-60, 180), "shoulder_abduction": (-30, 78),
    "shoulder_rotation": (-90, 70), "elbow_flexion": (-5, 150),
    "forearm_pronation": (-85, 85), "wrist_flexion": (-70, 80), "wrist_deviation": (-20, 30),
}


def random_angles(n, seed):
    rng = np.random.default_rng(seed)
    return {k: rng.uniform(lo, hi, n) * DEG for k, (lo, hi) in LIMITS_DEG.items()}


def world(pose, R_world_thorax):
    return {k: R_world_thorax @ v for k, v in pose.R_thorax.items()}


@pytest.mark.parametrize("side", ["right", "left"])
def test_exact_inverse_over_random_angles(side):
    """Each pose solved on its own (a fresh solver per sample: no history to lean on)."""
    n = 3000
    angles = random_angles(n, seed=hash(side) % 1000)
    pose = forward_kinematics(angles, side, LENGTHS)
    R_world_thorax = Rotation.random(n, rng=np.random.default_rng(5)).as_matrix()
    R_world = world(pose, R_world_thorax)
    worst = 0.0
    for i in range(n):
        result = joint_angles({k: v[i:i + 1] for k, v in R_world.items()}, side)
        worst = max(worst, max(abs(result.angles[k][0] - angles[k][i]) for k in ANGLE_NAMES))
        assert max(abs(r[0]) for r in result.residuals.values()) < 1e-9
    print(f"{side}: worst joint-angle error over {n} random poses {worst / DEG:.1e} deg")
    assert worst < 1e-9


def test_batch_inverse_of_a_smooth_motion_and_elevation():
    t = np.linspace(0, 10, 2001)
    angles = {k: ((lo + hi) / 2 + (hi - lo) / 2.2 * np.sin(0.3 * (i + 1) * t)) * DEG
              for i, (k, (lo, hi)) in enumerate(LIMITS_DEG.items())}
    pose = forward_kinematics(angles, "right", LENGTHS)
    result = joint_angles(pose.R_thorax, "right")
    for k in ANGLE_NAMES:
        np.testing.assert_allclose(result.angles[k], angles[k], atol=1e-10, err_msg=k)
    down = np.array([0.0, -1.0, 0.0])
    cos_elev = (pose.R_thorax["upper_arm"] @ down) @ down
    np.testing.assert_allclose(np.cos(result.angles["shoulder_elevation"]), cos_elev, atol=1e-12)
    assert list(result.angles) == list(REPORTED_ANGLES)


def test_angles_do_not_depend_on_the_heading_of_the_room():
    angles = random_angles(500, seed=3)
    pose = forward_kinematics(angles, "right", LENGTHS)
    a = joint_angles(pose.R_thorax, "right")
    b = joint_angles(world(pose, Rotation.random(rng=np.random.default_rng(1)).as_matrix()),
                     "right")
    for k in REPORTED_ANGLES:
        np.testing.assert_allclose(a.angles[k], b.angles[k], atol=1e-12)


def test_missing_segments_leave_their_joints_at_zero():
    angles = random_angles(200, seed=4)
    angles["shoulder_abduction"] = angles["shoulder_abduction"] / 2  # clear of the singularity
    pose = forward_kinematics(angles, "right", LENGTHS)
    only = {k: pose.R_thorax[k] for k in ("upper_arm", "forearm")}
    result = joint_angles(only, "right")
    for k in ("clavicle_protraction", "clavicle_elevation", "wrist_flexion", "wrist_deviation"):
        np.testing.assert_array_equal(result.angles[k], 0.0)
    # Without a clavicle sensor the shoulder angles are humerothoracic: Z·X·Y of
    # R_thorax_humerus. (Random poses in a row are no motion: compare modulo 2π.)
    humerothoracic = joint_angles({"upper_arm": pose.R_thorax["upper_arm"]}, "right")
    zxy = Rotation.from_matrix(pose.R_thorax["upper_arm"]).as_euler("ZXY")
    expected = {"shoulder_flexion": zxy[:, 0], "shoulder_abduction": -zxy[:, 1],
                "shoulder_rotation": zxy[:, 2]}
    for k, v in expected.items():
        gap = np.angle(np.exp(1j * (humerothoracic.angles[k] - v)))
        np.testing.assert_allclose(gap, 0.0, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(humerothoracic.angles["shoulder_elevation"],
                               result.angles["shoulder_elevation"], atol=1e-12)


def test_residual_measures_what_a_two_dof_joint_cannot_do():
    """An elbow turned 7° about its own X axis (a misaligned sensor, a soft-tissue artefact)
    shows as a 7° carrying angle, and flexion and pronation stay exact."""
    angles = random_angles(100, seed=6)
    pose = forward_kinematics(angles, "right", LENGTHS)
    R_world = dict(pose.R_thorax)
    R_world["forearm"] = (pose.R_thorax["upper_arm"] @ elemental("z", angles["elbow_flexion"])
                          @ elemental("x", 7 * DEG) @ elemental("y", angles["forearm_pronation"]))
    R_world["hand"] = R_world["forearm"] @ (
        np.swapaxes(pose.R_thorax["forearm"], -1, -2) @ pose.R_thorax["hand"])
    result = joint_angles(R_world, "right")
    np.testing.assert_allclose(result.residuals["elbow_carrying"], 7 * DEG, atol=1e-12)
    for k in ("elbow_flexion", "forearm_pronation", "wrist_flexion", "wrist_deviation"):
        np.testing.assert_allclose(result.angles[k], angles[k], atol=1e-12)
    np.testing.assert_allclose(result.residuals["wrist_twist"], 0.0, atol=1e-12)


def singular_motion(n=4001, duration=20.0):
    """Abduction 0 → 90 (held 4 s) → 150 → 90 → 0, flexion still while near 90°, rotation
    moving throughout."""
    t = np.linspace(0, duration, n)
    abduction = np.interp(t, [0, 4, 8, 12, 16, 20], [0, 90, 90, 150, 90, 0]) * DEG
    flexion = np.interp(t, [0, 2, 3, 17, 18, 20], [0, 15, 20, 20, 10, 0]) * DEG
    rotation = (-10 + 15 * np.sin(0.5 * t)) * DEG
    return {"shoulder_flexion": flexion, "shoulder_abduction": abduction,
            "shoulder_rotation": rotation, "elbow_flexion": np.full(n, 40 * DEG)}


@pytest.mark.parametrize("side", ["right", "left"])
def test_through_the_shoulder_singularity_exact(side):
    truth = singular_motion()
    pose = forward_kinematics(truth, side, LENGTHS)
    result = joint_angles(pose.R_thorax, side)
    for k in truth:
        np.testing.assert_allclose(result.angles[k], truth[k], atol=1e-9, err_msg=k)


@pytest.mark.parametrize("side", ["right", "left"])
def test_through_the_shoulder_singularity_noisy(side):
    """Orientation noise of 0.03° rms per axis (the jitter of a filtered orientation):
    flexion and rotation stay within 1° of the truth, abduction goes on past 90° with no
    180° flip, and elevation stays exact up to the noise."""
    truth = singular_motion()
    pose = forward_kinematics(truth, side, LENGTHS)
    rng = np.random.default_rng(11)
    noise = Rotation.from_rotvec(rng.normal(0, 0.03 * DEG, (len(truth["shoulder_flexion"]), 3)))
    R_world = {"upper_arm": pose.R_thorax["upper_arm"] @ noise.as_matrix(),
               "forearm": pose.R_thorax["forearm"]}
    result = joint_angles(R_world, side)
    errors = {k: np.abs(result.angles[k] - truth[k]).max() / DEG
              for k in ("shoulder_flexion", "shoulder_abduction", "shoulder_rotation")}
    print(f"{side}: worst error through 90° abduction (deg): "
          + ", ".join(f"{k} {v:.2f}" for k, v in errors.items()))
    assert max(errors.values()) < 1.0, errors
    assert result.angles["shoulder_abduction"].max() / DEG > 149


def test_exactly_at_the_singularity_rotation_takes_the_rest():
    n = 400
    flexion = np.r_[np.full(100, 30 * DEG), np.full(300, 30 * DEG)]
    abduction = np.r_[np.linspace(0, 90, 100), np.full(300, 90)] * DEG
    rotation = np.r_[np.zeros(100), np.linspace(0, 50, 300)] * DEG
    truth = {"shoulder_flexion": flexion, "shoulder_abduction": abduction,
             "shoulder_rotation": rotation}
    result = joint_angles(forward_kinematics(truth, "right", LENGTHS).R_thorax, "right")
    held = result.angles["shoulder_flexion"][100:]
    np.testing.assert_allclose(held, 30 * DEG, atol=1e-9)
    np.testing.assert_allclose(result.angles["shoulder_rotation"][100:], rotation[100:],
                               atol=1e-9)
    assert n == len(result.angles["shoulder_rotation"])


def test_starting_above_ninety_degrees_reads_the_anatomical_branch():
    truth = {"shoulder_abduction": np.full(10, 120 * DEG), "shoulder_flexion": np.zeros(10)}
    result = joint_angles(forward_kinematics(truth, "right", LENGTHS).R_thorax, "right")
    np.testing.assert_allclose(result.angles["shoulder_abduction"], 120 * DEG, atol=1e-12)
    np.testing.assert_allclose(result.angles["shoulder_flexion"], 0.0, atol=1e-12)
    np.testing.assert_allclose(result.angles["shoulder_rotation"], 0.0, atol=1e-12)


@given(st.lists(st.integers(1, 700), min_size=1, max_size=12), st.sampled_from(["right", "left"]))
@settings(max_examples=25, deadline=None)
def test_streaming_in_chunks_equals_batch(chunk_sizes, side):
    truth = singular_motion(n=2001)
    pose = forward_kinematics(truth, side, LENGTHS)
    R_world = {"upper_arm": pose.R_thorax["upper_arm"], "forearm": pose.R_thorax["forearm"]}
    batch = joint_angles(R_world, side)
    solver = JointAngleSolver(side)
    bounds = np.cumsum([0, *chunk_sizes])
    bounds = np.unique(np.r_[bounds[bounds < 2001], 2001])
    parts = [solver.update({k: v[a:b] for k, v in R_world.items()})
             for a, b in itertools.pairwise(bounds)]
    for k in REPORTED_ANGLES:
        np.testing.assert_allclose(np.concatenate([p.angles[k] for p in parts]),
                                   batch.angles[k], atol=1e-12, rtol=0, err_msg=k)


def test_bad_input_is_named():
    with pytest.raises(InvalidArgument, match="humerus"):
        joint_angles({"humerus": np.eye(3)[None]}, "right")
    with pytest.raises(InvalidShape, match=r"\(N, 3, 3\)"):
        joint_angles({"upper_arm": np.eye(3)}, "right")
    with pytest.raises(InvalidArgument, match="singular_zone"):
        JointAngleParams(singular_zone=1.0)
    with pytest.raises(InvalidArgument, match="side"):
        JointAngleSolver("up")
