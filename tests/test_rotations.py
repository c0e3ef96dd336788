"""Rotation primitives against scipy, on thousands of random rotations and batch shapes."""

import numpy as np
import pytest
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.rotations import (
    angle_between,
    elemental,
    matrix_to_quat,
    mirror_sagittal,
    quat_to_matrix,
    tait_bryan_angles,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

SEQUENCES = ["zxy", "xzy", "yxz", "xyz", "zyx", "yzx"]


@pytest.fixture(scope="module")
def random_matrices():
    return Rotation.random(5000, rng=np.random.default_rng(7)).as_matrix()


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_elemental_matches_scipy(axis):
    angles = np.random.default_rng(1).uniform(-4, 4, 1000)
    expected = Rotation.from_euler(axis, angles[:, None]).as_matrix()
    np.testing.assert_allclose(elemental(axis, angles), expected, atol=1e-15)


@pytest.mark.parametrize("sequence", SEQUENCES)
def test_tait_bryan_matches_scipy_and_recomposes(sequence, random_matrices):
    a, b, c = tait_bryan_angles(random_matrices, sequence)
    expected = Rotation.from_matrix(random_matrices).as_euler(sequence.upper())
    np.testing.assert_allclose(np.stack([a, b, c], axis=-1), expected, atol=1e-12)
    recomposed = elemental(sequence[0], a) @ elemental(sequence[1], b) @ elemental(sequence[2], c)
    np.testing.assert_allclose(recomposed, random_matrices, atol=1e-14)


@pytest.mark.parametrize("sequence", SEQUENCES)
@pytest.mark.parametrize("middle", [np.pi / 2, -np.pi / 2])
def test_tait_bryan_at_gimbal_lock_recomposes(sequence, middle):
    rng = np.random.default_rng(3)
    a0, c0 = rng.uniform(-np.pi, np.pi, (2, 200))
    R = elemental(sequence[0], a0) @ elemental(sequence[1], middle) @ elemental(sequence[2], c0)
    a, b, c = tait_bryan_angles(R, sequence)
    assert not np.isnan(a).any()
    recomposed = elemental(sequence[0], a) @ elemental(sequence[1], b) @ elemental(sequence[2], c)
    np.testing.assert_allclose(recomposed, R, atol=1e-7)


@given(st.sampled_from([(), (1,), (3, 1, 2)]), st.integers(0, 2**32 - 1))
@settings(max_examples=30, deadline=None)
def test_quaternion_round_trip_and_sign(shape, seed):
    n = int(np.prod(shape)) if shape else 1
    q = Rotation.random(n, rng=np.random.default_rng(seed)).as_quat(scalar_first=True)
    q = q.reshape(*shape, 4) if shape else q[0]
    R = quat_to_matrix(q)
    assert R.shape == (*shape, 3, 3)
    np.testing.assert_allclose(quat_to_matrix(-q), R, atol=1e-15)  # q and -q: one rotation
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-14)
    back = matrix_to_quat(R)
    assert back.shape == (*shape, 4)
    np.testing.assert_allclose(np.linalg.norm(back, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=-1)), 1.0, atol=1e-12)


def test_mirror_is_conjugation_by_sagittal_reflection(random_matrices):
    M = np.diag([1.0, 1.0, -1.0])
    np.testing.assert_array_equal(mirror_sagittal(random_matrices), M @ random_matrices @ M)
    # X and Y rotations change sign, Z rotations stay
    np.testing.assert_allclose(mirror_sagittal(elemental("x", 0.3)), elemental("x", -0.3))
    np.testing.assert_allclose(mirror_sagittal(elemental("y", 0.3)), elemental("y", -0.3))
    np.testing.assert_allclose(mirror_sagittal(elemental("z", 0.3)), elemental("z", 0.3))


def test_angle_between_is_accurate_near_zero_and_pi():
    u = np.array([0.0, -1.0, 0.0])
    for angle in [1e-9, 1e-4, 0.5, np.pi - 1e-6, np.pi]:
        v = elemental("x", angle) @ u
        assert angle_between(u, v) == pytest.approx(angle, abs=1e-15)


def test_bad_input_is_named():
    with pytest.raises(InvalidArgument, match="axis"):
        elemental("w", 0.1)
    with pytest.raises(InvalidArgument, match="sequence"):
        tait_bryan_angles(np.eye(3), "zxz")
    with pytest.raises(InvalidShape, match=r"\(\.\.\., 3, 3\)"):
        tait_bryan_angles(np.eye(4), "zxy")


def test_the_scalar_matrix_to_quaternion_agrees_with_the_array_one():
    from armtrack.estimator.scalar_rotations import quat_from_rows

    rng = np.random.default_rng(5)
    q = rng.normal(size=(2000, 4))
    q[:4] = np.eye(4)  # the pivots' edge cases: identity and half turns about each axis
    R = quat_to_matrix(q)
    scalar = np.array([quat_from_rows(*m.ravel().tolist()) for m in R])
    assert np.abs(scalar - matrix_to_quat(R)).max() < 1e-14
