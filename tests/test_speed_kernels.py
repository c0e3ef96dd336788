"""Issue 18's speed work changes no number. The compiled heading-constraint pass
(``pipeline/constraints._constrain``) turns the segments as the correction ``update``
gives, applied with ``elemental('z', δ) @ R``, in any chunking, and its pure-Python
fallback gives the compiled numbers; the joint angles worked in blocks of the kernel's
work space (``arm/compiled._chunk_python``) equal those of small chunks."""

import itertools

import numpy as np
import pytest
from armtrack.estimator.pipeline import constraints
from armtrack.estimator.pipeline.constraints import DRIFT_RATE_PRIOR, HeadingConstraint
from armtrack.estimator.rotations import elemental, quat_to_matrix


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    return quat_to_matrix(q / np.linalg.norm(q, axis=1)[:, None])


def stack(rng, n=1500):
    """R_world_segment (n, 5, 3, 3) of a slowly turning chain, times at ~100 Hz."""
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    base = random_rotations(rng, 5)
    turn = np.stack([elemental("y", 0.8 * np.sin(0.7 * t + k)) for k in range(5)], axis=1)
    return t, turn @ base[None]


def test_apply_turns_the_segments_as_update_and_elemental_do():
    rng = np.random.default_rng(5)
    t, Rw = stack(rng)
    # the forearm (2) by the elbow (upper arm Z, forearm Y), the hand (3) with it
    expected = Rw.copy()
    delta = HeadingConstraint().update(t, Rw[:, 1, :, 2], Rw[:, 2, :, 1])
    expected[:, 2] = elemental("z", delta) @ Rw[:, 2]
    expected[:, 3] = elemental("z", delta) @ Rw[:, 3]
    got = Rw.copy()
    chunked = HeadingConstraint()
    for a in range(0, len(t), 97):
        part = got[a:a + 97]
        chunked.apply(t[a:a + 97], part, 1, 2, 2, 1, (2, 3))
    print(f"heading correction up to {np.rad2deg(np.abs(delta).max()):.2f}°")
    assert np.abs(delta).max() > np.deg2rad(1.0)  # the case does turn the segments
    np.testing.assert_allclose(got, expected, atol=1e-12)
    np.testing.assert_array_equal(got[:, (0, 1, 4)], Rw[:, (0, 1, 4)])


def steps_taken_back(rng, t):
    """Child's and parent's drift taken back [rad] (N, 2), stepping at rests, and the knots
    [s] (N, 2) their gaps count from (NaN before the first rest)."""
    taken, knots = np.zeros((len(t), 2)), np.full((len(t), 2), np.nan)
    for j in range(2):
        rests = np.sort(rng.choice(len(t), 6, replace=False))
        for a, b in itertools.pairwise(rests):
            taken[b:, j] += rng.normal(0.0, 0.02)
            knots[a:, j] = t[a]
    return taken, knots


def test_apply_with_steps_taken_back_in_chunks_gives_the_whole():
    rng = np.random.default_rng(8)
    t, Rw = stack(rng)
    taken, knots = steps_taken_back(rng, t)
    whole = Rw.copy()
    delta = HeadingConstraint().apply(t, whole, 1, 2, 2, 1, (2, 3), taken, knots)
    chunked, got = HeadingConstraint(), Rw.copy()
    for a in range(0, len(t), 97):
        chunked.apply(t[a:a + 97], got[a:a + 97], 1, 2, 2, 1, (2, 3), taken[a:a + 97],
                      knots[a:a + 97])
    plain = HeadingConstraint().apply(t, Rw.copy(), 1, 2, 2, 1, (2, 3))
    print(f"steps turn the correction by up to {np.rad2deg(np.abs(delta - plain).max()):.2f}°")
    assert np.abs(delta - plain).max() > np.deg2rad(0.1)  # the steps do reach the joint
    np.testing.assert_allclose(got, whole, atol=1e-12)
    # the same with the drift's rate fitted
    whole = Rw.copy()
    HeadingConstraint(rate_prior=DRIFT_RATE_PRIOR).apply(t, whole, 1, 2, 2, 1, (2, 3), taken,
                                                         knots)
    chunked, got = HeadingConstraint(rate_prior=DRIFT_RATE_PRIOR), Rw.copy()
    for a in range(0, len(t), 97):
        chunked.apply(t[a:a + 97], got[a:a + 97], 1, 2, 2, 1, (2, 3), taken[a:a + 97],
                      knots[a:a + 97])
    np.testing.assert_allclose(got, whole, atol=1e-12)


def test_pure_python_fallback_gives_the_compiled_numbers():
    rng = np.random.default_rng(6)
    t, Rw = stack(rng, 400)
    taken, knots = steps_taken_back(rng, t)
    # between two sensors; against a virtual upper arm; with the drift's rate and without
    for gate, rate_prior in ((np.inf, np.inf), (0.1, np.inf), (np.inf, 20.0), (0.1, 20.0)):
        outs = []
        for kernel in (constraints._constrain, constraints._constrain_python):
            R, delta = Rw.copy(), np.empty(len(t))
            state = np.zeros(constraints.CONSTRAIN_STATE_SIZE)
            kernel(t, R, 2, 3, 0, 2, np.array([3]), 20.0, 0.05, rate_prior, gate, state, delta,
                   taken, knots)
            outs.append((R, state, delta))
        for compiled, python in zip(*outs, strict=True):
            np.testing.assert_allclose(compiled, python, atol=1e-12)


def test_joint_angles_in_blocks_equal_small_chunks():
    from armtrack.estimator.arm.compiled import _BLOCK, CompiledJoints
    from armtrack.estimator.body import SegmentLengths
    from armtrack.estimator.pipeline.session import PipelineConfig

    rng = np.random.default_rng(7)
    n = 2 * _BLOCK + 333  # three blocks, the last one short
    _, Rw = stack(rng, n)
    present = np.array([1.0, 0.0, 1.0, 1.0, 1.0])
    params = PipelineConfig(side="right", lengths=SegmentLengths.from_height(1.7),
                            sensors=("upper_arm",)).joint_params
    whole = CompiledJoints("right", SegmentLengths.from_height(1.7), params).update(Rw, present)
    chunked = CompiledJoints("right", SegmentLengths.from_height(1.7), params)
    parts = [chunked.update(Rw[a:a + 7], present) for a in range(0, n, 7)]
    for i, got in enumerate(whole):
        np.testing.assert_array_equal(got, np.concatenate([p[i] for p in parts]))


def test_mean_turn_is_elemental_z_by_the_weighted_mean_compiled_or_not():
    """The whole arm's turn to its sensors' weighted mean heading (6-axis kits): each
    sample's chain by ``elemental('z', −Σ wⱼ offsetⱼ / Σ w)`` with ``w = 1 / (floor +
    turned)``, the other segments untouched."""
    rng = np.random.default_rng(8)
    _, Rw = stack(rng, 300)
    offsets = rng.uniform(-0.2, 0.2, (3, len(Rw)))  # each sensor's own, drift taken back
    turned = rng.uniform(0.0, 50.0, (3, len(Rw)))
    w = 1.0 / (1.0 + turned)
    angle = -(w * offsets).sum(axis=0) / w.sum(axis=0)
    expected = Rw.copy()
    for s in (1, 2, 3):
        expected[:, s] = elemental("z", angle) @ Rw[:, s]
    for kernel in (constraints.mean_turn, constraints._mean_turn_python):
        got = Rw.copy()
        kernel(got, np.array([1, 2, 3], dtype=np.int64), offsets, turned, 1.0)
        np.testing.assert_allclose(got, expected, atol=1e-12)
        np.testing.assert_array_equal(got[:, (0, 4)], Rw[:, (0, 4)])
        with pytest.raises(ValueError):  # one offset row per segment, or no turn at all
            kernel(Rw.copy(), np.array([1, 2, 3], dtype=np.int64), offsets[:2], turned, 1.0)


def test_angle_turned_in_chunks_equals_whole_compiled_or_not():
    """∫|ω| dt up to each estimate time, carried from chunk to chunk as the pipeline
    does (each chunk starts at the last sample at or before the previous one's end)."""
    rng = np.random.default_rng(9)
    t = np.cumsum(rng.uniform(0.008, 0.012, 500))
    gyr = rng.normal(size=(500, 3))
    times = np.sort(rng.uniform(t[0], t[-1], 200))
    step = np.diff(t) * np.linalg.norm(gyr[1:], axis=1)
    expected = np.concatenate([[0.0], np.cumsum(step)])[np.searchsorted(t, times, "right") - 1]
    for kernel in (constraints.turned_angle, constraints._turned_python):
        state, parts = np.zeros(1), []
        for a in range(0, len(times), 37):
            chunk = times[a:a + 37]
            first = int(np.searchsorted(t, times[a - 1], "right")) - 1 if a else 0
            out = np.empty(len(chunk))
            kernel(t[first:], gyr[first:], chunk, state, out)
            parts.append(out)
        np.testing.assert_allclose(np.concatenate(parts), expected, rtol=1e-12)


def test_one_symmetric_3x3_inverse_for_the_qcf_kernel_and_the_drift_take_back():
    """The qcf kernel's bias updates and the drift take-back's Kalman step invert their
    symmetric 3×3 matrix with one compiled helper (it was written in each): its cofactors
    over its determinant are numpy's inverse, compiled or not, bit for bit alike."""
    from armtrack.estimator import scalar_linalg
    from armtrack.estimator.orientation import qcf_kernel
    from armtrack.estimator.pipeline import drift

    assert qcf_kernel.sym3_adjugate is drift.sym3_adjugate is scalar_linalg.sym3_adjugate
    rng = np.random.default_rng(3)
    worst = 0.0
    for scale in (1e-10, 1e-6, 1.0, 1e3):  # rad²/s² covariances to large ones
        a = rng.normal(size=(3, 3)) * np.sqrt(scale)
        s = a @ a.T + scale * 1e-3 * np.eye(3)
        upper = (s[0, 0], s[1, 1], s[2, 2], s[0, 1], s[0, 2], s[1, 2])
        c00, c01, c02, c11, c12, c22, det = scalar_linalg.sym3_adjugate(*upper)
        assert (c00, c01, c02, c11, c12, c22, det) == scalar_linalg._sym3_adjugate(*upper)
        inverse = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) / det
        expected = np.linalg.inv(s)
        worst = max(worst, np.abs(inverse - expected).max() / np.abs(expected).max())
        assert det == pytest.approx(np.linalg.det(s), rel=1e-9)
    print(f"\nlargest relative difference from numpy's inverse: {worst:.1e}")
    assert worst < 1e-9
