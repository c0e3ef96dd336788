"""The compiled per-sample joint angles and forward kinematics equal the numpy reference
(``JointAngleSolver`` then ``forward_kinematics``) to 1e-9, through the singularity, on
both sides, in chunks — compiled and pure Python alike."""

import itertools

import numpy as np
import pytest
from armtrack.estimator.arm import (
    ANGLE_NAMES,
    REPORTED_ANGLES,
    JointAngleSolver,
    forward_kinematics,
)
from armtrack.estimator.arm.compiled import COMPILED, STATE_SIZE, _kernel_python, kernel
from armtrack.estimator.arm.inverse import _relative_rotations
from armtrack.estimator.arm.joints import NORMAL_RANGE_DEG
from armtrack.estimator.body import SegmentLengths
from scipy.spatial.transform import Rotation

LENGTHS = SegmentLengths.from_height(1.7)
NORMAL = np.deg2rad([NORMAL_RANGE_DEG[f"shoulder_{n}"]
                     for n in ("flexion", "abduction", "rotation")])


def motion(n=3000, seed=0):
    """Every joint moving, abduction 0 → 150° and back through the singular zone, and a
    little orientation noise so the zone's edges are crossed back and forth."""
    t = np.linspace(0, 30, n)
    rng = np.random.default_rng(seed)
    angles = {name: np.deg2rad(20 * np.sin(0.3 * (i + 1) * t + i)) for i, name in
              enumerate(ANGLE_NAMES)}
    angles["shoulder_abduction"] = np.deg2rad(np.interp(t, [0, 8, 12, 16, 20, 30],
                                                        [0, 90, 90, 150, 90, 0]))
    angles["elbow_flexion"] = np.deg2rad(60 + 50 * np.sin(0.4 * t))
    pose = forward_kinematics(angles, "right", LENGTHS)
    noise = Rotation.from_rotvec(rng.normal(0, np.deg2rad(0.05), (n, 3))).as_matrix()
    return {k: (v @ noise if k != "thorax" else v) for k, v in pose.R_thorax.items()}


def run(run_kernel, rel, side, chunks):
    state = np.zeros(STATE_SIZE)
    n = len(rel)
    angles, residuals = np.empty((n, 10)), np.empty((n, 3))
    positions, R = np.empty((n, 4, 3)), np.empty((n, 4, 3, 3))
    bounds = np.unique(np.r_[0, np.cumsum(chunks), n].clip(0, n))
    for a, b in itertools.pairwise(bounds):
        run_kernel(rel[a:b], 1.0 if side == "right" else -1.0,
                   np.array([LENGTHS.clavicle, LENGTHS.upper_arm, LENGTHS.forearm,
                             LENGTHS.hand]), np.sin(np.deg2rad(10.0)), NORMAL, state,
                   angles[a:b], residuals[a:b], positions[a:b], R[a:b])
    return angles, residuals, positions, R


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("which", ["compiled", "python"])
def test_equals_the_numpy_reference(side, which):
    if which == "compiled" and not COMPILED:
        pytest.skip("numba is not installed")
    R_world = motion(seed=1 if side == "right" else 2)
    if side == "left":
        M = np.diag([1.0, 1.0, -1.0])
        R_world = {k: M @ v @ M for k, v in R_world.items()}
    reference = JointAngleSolver(side).update(R_world)
    pose = forward_kinematics({k: v for k, v in reference.angles.items()
                               if k != "shoulder_elevation"}, side, LENGTHS)
    rel = np.stack([v for k, v in _relative_rotations(R_world, side).items()], axis=1)
    angles, residuals, positions, R = run(kernel if which == "compiled" else _kernel_python,
                                          rel, side, chunks=[700, 1, 999, 300])
    for i, name in enumerate(REPORTED_ANGLES):
        np.testing.assert_allclose(angles[:, i], reference.angles[name], atol=1e-9,
                                   err_msg=name)
    for i, name in enumerate(("clavicle_axial", "elbow_carrying", "wrist_twist")):
        np.testing.assert_allclose(residuals[:, i], reference.residuals[name], atol=1e-9)
    for i, point in enumerate(("shoulder", "elbow", "wrist", "hand")):
        np.testing.assert_allclose(positions[:, i], pose.p_thorax[point], atol=1e-12)
    for i, segment in enumerate(("clavicle", "upper_arm", "forearm", "hand")):
        np.testing.assert_allclose(R[:, i], pose.R_thorax[segment], atol=1e-12)
    assert np.rad2deg(angles[:, 3]).max() > 149  # abduction went past 90° on its branch


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("present", [("thorax", "clavicle", "upper_arm", "forearm", "hand"),
                                     ("upper_arm", "forearm"), ("forearm",),
                                     ("thorax", "upper_arm", "hand")])
def test_relative_rotations_equal_the_numpy_reference(side, present):
    from armtrack.estimator.arm.compiled import _relative_python, relative
    from armtrack.estimator.arm.joints import SEGMENTS

    R_world = {k: v for k, v in motion(n=400, seed=3).items() if k in present}
    R_world = {k: Rotation.random(rng=np.random.default_rng(1)).as_matrix() @ v
               for k, v in R_world.items()}
    expected = np.stack(list(_relative_rotations(R_world, side).values()), axis=1)
    Rw = np.empty((400, 5, 3, 3))
    flags = np.zeros(5)
    for i, s in enumerate(SEGMENTS):
        if s in R_world:
            Rw[:, i], flags[i] = R_world[s], 1.0
    for run_relative in (relative, _relative_python):
        out = np.empty((400, 4, 3, 3))
        run_relative(Rw, flags, 1.0 if side == "right" else -1.0, out)
        np.testing.assert_allclose(out, expected, atol=1e-14)
