"""Forward kinematics against the elemental rotations of spec/kinematics.md (via scipy)."""

import numpy as np
import pytest
from armtrack.estimator.arm import ANGLE_NAMES, forward_kinematics
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument
from scipy.spatial.transform import Rotation

LENGTHS = SegmentLengths.from_height(1.80)
M = np.diag([1.0, 1.0, -1.0])


def random_angles(n, seed=0):
    rng = np.random.default_rng(seed)
    return {name: rng.uniform(-np.pi, np.pi, n) for name in ANGLE_NAMES}


def scipy_chain(a):
    """The spec's chain written independently with scipy's intrinsic Euler sequences."""
    def euler(seq, *angles):
        return Rotation.from_euler(seq, np.stack(angles, axis=-1)).as_matrix()

    R_tc = euler("YX", a["clavicle_protraction"], -a["clavicle_elevation"])
    R_ch = euler("ZXY", a["shoulder_flexion"], -a["shoulder_abduction"], a["shoulder_rotation"])
    R_hf = euler("ZY", a["elbow_flexion"], a["forearm_pronation"])
    R_fp = euler("XZ", a["wrist_flexion"], -a["wrist_deviation"])
    return {"clavicle": R_tc, "upper_arm": R_tc @ R_ch, "forearm": R_tc @ R_ch @ R_hf,
            "hand": R_tc @ R_ch @ R_hf @ R_fp}


def test_segment_lengths_from_height_follow_the_paper():
    lengths = SegmentLengths.from_height(1.70)
    assert lengths.as_dict() == pytest.approx(
        {"clavicle": 0.129 * 1.7, "upper_arm": 0.186 * 1.7, "forearm": 0.146 * 1.7,
         "hand": 0.108 * 1.7})
    with pytest.raises(InvalidArgument, match="height"):
        SegmentLengths.from_height(17.0)


def test_zero_pose_is_the_n_pose():
    pose = forward_kinematics({}, "right", LENGTHS)
    for R in pose.R_thorax.values():
        np.testing.assert_array_equal(R, np.eye(3))
    lc, lu, lf, lh = LENGTHS.clavicle, LENGTHS.upper_arm, LENGTHS.forearm, LENGTHS.hand
    np.testing.assert_allclose(pose.p_thorax["shoulder"], [0, 0, lc])
    np.testing.assert_allclose(pose.p_thorax["elbow"], [0, -lu, lc])
    np.testing.assert_allclose(pose.p_thorax["wrist"], [0, -lu - lf, lc])
    np.testing.assert_allclose(pose.p_thorax["hand"], [0, -lu - lf - lh, lc])
    left = forward_kinematics({}, "left", LENGTHS)
    np.testing.assert_allclose(left.p_thorax["hand"], [0, -lu - lf - lh, -lc])


def test_orientations_and_positions_match_independent_composition():
    angles = random_angles(4000)
    pose = forward_kinematics(angles, "right", LENGTHS)
    expected = scipy_chain(angles)
    for segment, R in expected.items():
        np.testing.assert_allclose(pose.R_thorax[segment], R, atol=1e-13)
    down = np.array([0.0, -1.0, 0.0])
    shoulder = expected["clavicle"] @ np.array([0, 0, LENGTHS.clavicle])
    elbow = shoulder + LENGTHS.upper_arm * expected["upper_arm"] @ down
    wrist = elbow + LENGTHS.forearm * expected["forearm"] @ down
    hand = wrist + LENGTHS.hand * expected["hand"] @ down
    for name, p in {"shoulder": shoulder, "elbow": elbow, "wrist": wrist, "hand": hand}.items():
        np.testing.assert_allclose(pose.p_thorax[name], p, atol=1e-13)


def test_left_arm_is_the_mirror_image():
    angles = random_angles(2000, seed=1)
    right = forward_kinematics(angles, "right", LENGTHS)
    left = forward_kinematics(angles, "left", LENGTHS)
    for segment in right.R_thorax:
        np.testing.assert_allclose(left.R_thorax[segment], M @ right.R_thorax[segment] @ M,
                                   atol=1e-15)
    for point in right.p_thorax:
        np.testing.assert_allclose(left.p_thorax[point], right.p_thorax[point] @ M, atol=1e-15)


@pytest.mark.parametrize("side, lateral", [("right", 1.0), ("left", -1.0)])
@pytest.mark.parametrize(
    "angles, point, direction",
    [
        ({"shoulder_flexion": 90}, "elbow", [1, 0, 0]),  # arm forward
        ({"shoulder_flexion": -45}, "elbow", [-1, -1, 0]),  # extension: backward
        ({"shoulder_abduction": 90}, "elbow", [0, 0, "lat"]),  # T-pose: arm to the side
        ({"elbow_flexion": 90}, "wrist", [1, 0, 0]),  # forearm forward
        ({"elbow_flexion": 90, "shoulder_rotation": 90}, "wrist", [0, 0, "med"]),  # internal
        ({"wrist_flexion": 90}, "hand", [0, 0, "med"]),  # palmar: palm faces the thigh
        ({"wrist_deviation": 30}, "hand", [-1, 0, 0]),  # ulnar: little-finger side is back
        ({"clavicle_elevation": 30}, "shoulder", [0, 1, "lat"]),  # shrug: up
        ({"clavicle_protraction": 30}, "shoulder", [1, 0, "lat"]),  # forward
    ],
)
def test_clinical_signs(side, lateral, angles, point, direction):
    """Each positive angle moves its segment the way its clinical name says, on both sides."""
    rad = {k: np.deg2rad(v) for k, v in angles.items()}
    pose = forward_kinematics(rad, side, LENGTHS)
    proximal = {"elbow": "shoulder", "wrist": "elbow", "hand": "wrist"}.get(point)
    start = pose.p_thorax[proximal] if proximal else np.zeros(3)
    moved = pose.p_thorax[point] - start
    want = np.array([lateral if d == "lat" else -lateral if d == "med" else d
                     for d in direction], dtype=float)
    for axis in range(3):
        if want[axis] != 0:
            assert np.sign(moved[axis]) == np.sign(want[axis]), (angles, side, moved)


def test_pronation_turns_the_palm_down_with_the_elbow_flexed():
    for side in ("right", "left"):
        pose = forward_kinematics({"elbow_flexion": np.pi / 2, "forearm_pronation": np.pi / 2},
                                  side, LENGTHS)
        palm_normal_in_hand = np.array([0.0, 0.0, -1.0 if side == "right" else 1.0])  # medial
        np.testing.assert_allclose(pose.R_thorax["hand"] @ palm_normal_in_hand, [0, -1, 0],
                                   atol=1e-15)


@pytest.mark.parametrize("shape", [(), (1,), (3, 1, 2)])
def test_batch_shapes(shape):
    angles = {"shoulder_flexion": np.full(shape, 0.3), "elbow_flexion": 0.5}
    pose = forward_kinematics(angles, "right", LENGTHS)
    assert pose.R_thorax["hand"].shape == (*shape, 3, 3)
    assert pose.p_thorax["hand"].shape == (*shape, 3)
    assert not np.isnan(pose.p_thorax["hand"]).any()


def test_bad_input_is_named():
    with pytest.raises(InvalidArgument, match="shoulder_flex"):
        forward_kinematics({"shoulder_flex": 0.1}, "right", LENGTHS)
    with pytest.raises(InvalidArgument, match="side"):
        forward_kinematics({}, "both", LENGTHS)
