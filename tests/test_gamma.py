"""The closed-form γ: roots against a numerical root finder, exact arms (right and left) from
forward kinematics, the straight elbow and the degenerate poses, the seed as printed."""

import itertools
import warnings

import numpy as np
import pytest
from armtrack.estimator.arm import forward_kinematics
from armtrack.estimator.arm.gamma import gamma_coefficients, gamma_roots, solve_gamma
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

LENGTHS = SegmentLengths.from_height(1.75)
LU, LF = LENGTHS.upper_arm, LENGTHS.forearm
DEG = np.pi / 180
#: Thorax axes (X anterior, Y superior, Z right) in an upright world (z up).
R_UPRIGHT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
LIMITS_DEG = {
    "clavicle_protraction": (-30, 30), "clavicle_elevation": (-15, 40),
    "shoulder_flexion": (-60, 180), "shoulder_abduction": (0, 180),
    "shoulder_rotation": (-90, 70), "elbow_flexion": (5, 145), "forearm_pronation": (-85, 85),
}


def wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def rot_z(angle):
    """R_z about world up, from scipy (independent of the module's ``elemental``)."""
    angle = np.asarray(angle, dtype=float)
    return Rotation.from_euler("z", angle.reshape(-1, 1)).as_matrix().reshape(*angle.shape, 3, 3)


def random_arms(n, side, seed, lean_deg=15.0, **fixed_deg):
    """Exact arms: S, E, W and the true upper-arm orientation in a world where the thorax
    has a random heading, a lean of up to ``lean_deg`` and a random place; R̃ is the truth turned by
    -τ about the vertical, so the correction to find is γ = τ."""
    rng = np.random.default_rng(seed)
    angles = {k: rng.uniform(lo, hi, n) * DEG for k, (lo, hi) in LIMITS_DEG.items()}
    angles.update({k: np.full(n, v * DEG) for k, v in fixed_deg.items()})
    pose = forward_kinematics(angles, side, LENGTHS)
    axis = np.column_stack([rng.normal(size=(n, 2)), np.zeros(n)])
    lean = (axis / np.linalg.norm(axis, axis=1, keepdims=True)
            * rng.uniform(0, lean_deg * DEG, (n, 1)))
    R_world_thorax = (rot_z(rng.uniform(-np.pi, np.pi, n)) @ Rotation.from_rotvec(lean).as_matrix()
                      @ R_UPRIGHT)
    origin = np.column_stack([rng.uniform(-2, 2, (n, 2)), rng.uniform(1.2, 1.6, n)])

    def world(p):
        return origin + np.einsum("nij,nj->ni", R_world_thorax, p)

    R_true = R_world_thorax @ pose.R_thorax["upper_arm"]
    tau = rng.uniform(-np.pi, np.pi, n)
    return {"S": world(pose.p_thorax["shoulder"]), "E": world(pose.p_thorax["elbow"]),
            "W": world(pose.p_thorax["wrist"]), "R_true": R_true, "tau": tau,
            "R_tilt": rot_z(-tau) @ R_true, "flexion": angles["elbow_flexion"]}


def plane_distance(gamma, S, W, R_tilt):
    """The seed's eq. 1 corrected: signed distance [m] of W from the plane through S spanned
    by the X and Y axes of R_z(γ) R̃ (scipy's rotation, unit normal)."""
    normal = rot_z(gamma) @ R_tilt[..., :, 2, None]
    return np.sum(normal[..., 0] * (W - S), axis=-1)


def seed_as_printed(S, W, R, *, fix_p=False, fix_d=False, fix_b=False, fix_atan2=False):
    """Additional file 1 verbatim (its γ about g = (0, 0, -1)), with optional corrections.
    In a, b, c the seed's W̃ is read as Ŵ, the wrist before it is turned."""
    Wh = (W - S) / np.linalg.norm(W - S, axis=-1, keepdims=True)
    Px = R[..., :, 0] + (S if fix_p else 0.0)
    Py = R[..., :, 1] + (S if fix_p else 0.0)
    N = np.cross(Py - S, Py - Px)
    A, B, C = N[..., 0], N[..., 1], N[..., 2]
    D = np.sum(N * S, axis=-1) * (-1.0 if fix_d else 1.0)
    a = A * Wh[..., 0] + B * Wh[..., 1]
    b = A * Wh[..., 1] + (-1.0 if fix_b else 1.0) * B * Wh[..., 0]
    c = A * S[..., 0] + B * S[..., 1] + C * (Wh[..., 2] + S[..., 2]) + D
    m = np.hypot(a, b)
    with np.errstate(all="ignore"):
        eta = np.arctan2(-b, a) if fix_atan2 else np.arctan(-b / a)
        g1 = eta - np.arccos(-c / m)
        g2 = eta - np.arccos(-c / -m) - np.pi
    return g1, g2


# ---------------------------------------------------------------- roots vs a root finder
def test_closed_form_roots_equal_the_roots_of_a_numerical_finder():
    n, grid_n = 3000, 7200
    rng = np.random.default_rng(7)
    S = rng.uniform(-2, 2, (n, 3))
    W = S + rng.normal(size=(n, 3)) * rng.uniform(0.05, 0.8, (n, 1))
    R = Rotation.random(n, rng=rng).as_matrix()
    a, b, c = gamma_coefficients(S, W, R)
    g1, g2, reachable, degenerate = gamma_roots(a, b, c)
    assert not degenerate.any()

    # Closed form: the plane distance is zero at both roots.
    ok = reachable
    residual = np.abs(np.concatenate([plane_distance(g1[ok], S[ok], W[ok], R[ok]),
                                      plane_distance(g2[ok], S[ok], W[ok], R[ok])]))
    assert residual.max() < 1e-9, residual.max()
    assert np.isnan(g1[~ok]).all() and np.isnan(g2[~ok]).all()

    # Numerical: sign changes of the distance on a fine grid of γ, refined by brentq.
    grid = np.linspace(-np.pi, np.pi, grid_n + 1)
    outer = (W - S)[:, :, None] * R[:, None, :, 2]  # v_i ñ_j
    d_grid = (rot_z(grid).reshape(-1, 9) @ outer.reshape(n, 9).T).T  # (n, grid)
    step = grid[1] - grid[0]
    worst, missed_close_pairs, matched = 0.0, 0, 0
    for i in range(n):
        def f(g, i=i):
            return float(plane_distance(g, S[i], W[i], R[i]))
        crossings = np.flatnonzero(np.sign(d_grid[i, :-1]) * np.sign(d_grid[i, 1:]) <= 0)
        roots = [brentq(f, grid[j], grid[j + 1], xtol=1e-14) for j in crossings]
        roots = np.unique(np.round(wrap(roots), 11))
        if not reachable[i]:
            assert len(roots) == 0, (i, roots)
            continue
        if len(roots) == 0 and abs(wrap(g1[i] - g2[i])) < 2 * step:
            missed_close_pairs += 1  # both roots between two grid points: the grid's limit
            continue
        closed = np.array([g1[i], g2[i]])
        assert len(roots) == 2, (i, roots, closed)
        diff = np.abs(wrap(np.sort(wrap(closed))[:, None] - roots[None, :])).min(axis=1)
        worst = max(worst, diff.max())
        matched += 1
    print(f"\n{n} random (S, W, R̃): {reachable.sum()} reachable, {(~reachable).sum()} out of "
          f"reach (finder: no root either); {matched} with both roots equal to brentq's "
          f"(worst {worst:.1e} rad), {missed_close_pairs} pairs closer than the grid; "
          f"worst plane distance at the closed-form roots {residual.max():.1e} m")
    assert worst < 1e-9
    assert matched >= reachable.sum() - 5


# ---------------------------------------------------------------- exact arms
@pytest.mark.parametrize("side", ["right", "left"])
def test_exact_arms_recover_the_turn_and_the_elbow(side):
    n = 5000
    arm = random_arms(n, side, seed=11 if side == "right" else 12)
    sol = solve_gamma(arm["S"], arm["W"], arm["R_tilt"], LU, LF)
    gamma_error = np.abs(wrap(sol.gamma - arm["tau"]))
    elbow_error = np.linalg.norm(sol.p_world_elbow - arm["E"], axis=-1)
    R_error = np.abs(sol.R_world_humerus - arm["R_true"]).max(axis=(-2, -1))
    wrong = np.flatnonzero(~(elbow_error < 1e-9))

    # How much each half of the rule does: the other root, and what it would imply.
    other = np.where(sol.gamma == sol.gamma1, sol.gamma2, sol.gamma1)
    w = np.einsum("nji,nj->ni", rot_z(other) @ arm["R_tilt"], arm["W"] - arm["S"])
    flex_other = np.arctan2(w[:, 0], -(w[:, 1] + LU))
    len_other = np.abs(np.hypot(w[:, 0], w[:, 1] + LU) - LF)
    in_range = (flex_other >= -10 * DEG) & (flex_other <= 160 * DEG)
    print(f"\n{side}: {n} exact arms, elbow flexion 5…145°: {n - len(wrong)} elbows right to "
          f"1e-9 m (worst {elbow_error.max():.1e} m, γ {gamma_error.max():.1e} rad, "
          f"R {R_error.max():.1e}); the other root was rejected by the flexion range in "
          f"{(~in_range).sum()}, by the forearm length in {in_range.sum()} (its smallest "
          f"length error then {len_other[in_range].min() * 1e3:.2f} mm)")
    assert len(wrong) == 0, wrong[:10]
    assert gamma_error.max() < 1e-9
    assert R_error.max() < 1e-9
    assert sol.reachable.all() and not sol.degenerate.any() and sol.physiological.all()
    np.testing.assert_allclose(sol.elbow_flexion, arm["flexion"], atol=1e-9)
    np.testing.assert_allclose(sol.forearm_length_error, 0.0, atol=1e-9)


@pytest.mark.parametrize("side", ["right", "left"])
def test_flexion_swings_the_wrist_anterior_on_both_sides(side):
    """The rule's premise: in the upper arm's own frame positive flexion moves the wrist to
    +X, on a left arm too (its Z points medially, but Rz(φ) survives the mirror)."""
    flexion = np.linspace(0, 150, 16) * DEG
    pose = forward_kinematics({"elbow_flexion": flexion, "shoulder_abduction": 0.4,
                               "forearm_pronation": 0.7}, side, LENGTHS)
    R = pose.R_thorax["upper_arm"]
    w = np.einsum("nji,nj->ni", R, pose.p_thorax["wrist"] - pose.p_thorax["shoulder"])
    np.testing.assert_allclose(w[:, 0], LF * np.sin(flexion), atol=1e-12)
    np.testing.assert_allclose(w[:, 1], -LU - LF * np.cos(flexion), atol=1e-12)
    np.testing.assert_allclose(w[:, 2], 0.0, atol=1e-12)
    lateral = np.sign(pose.p_thorax["shoulder"][:, 2])  # thorax Z is to the subject's right
    z_lateral = lateral * R[:, 2, 2]  # the upper arm's Z axis, its thorax-Z part
    assert (z_lateral > 0).all() if side == "right" else (z_lateral < 0).all()


def test_the_two_roots_mirror_the_wrist_across_the_in_plane_up_direction():
    arm = random_arms(2000, "right", seed=3)
    sol = solve_gamma(arm["S"], arm["W"], arm["R_tilt"], LU, LF)
    v = arm["W"] - arm["S"]
    w1 = np.einsum("nji,nj->ni", rot_z(sol.gamma1) @ arm["R_tilt"], v)[:, :2]
    w2 = np.einsum("nji,nj->ni", rot_z(sol.gamma2) @ arm["R_tilt"], v)[:, :2]
    up = arm["R_tilt"][:, 2, :2]  # world up in the arm frame, in-plane part
    up = up / np.linalg.norm(up, axis=1, keepdims=True)
    mirrored = 2 * np.sum(w1 * up, axis=1, keepdims=True) * up - w1
    np.testing.assert_allclose(w2, mirrored, atol=1e-12)


# ---------------------------------------------------------------- straight elbow, degenerate
def test_straight_elbow_still_determines_gamma():
    """Elbow at 0°: S, E, W collinear, but the plane's tilt comes from R̃, so γ is still
    determined and E = S + l_u (W - S)/|W - S|. The roots merge (γ ill-conditioned, error
    ~√ε) only where the arm's X axis is also horizontal."""
    n = 5000
    arm = random_arms(n, "right", seed=5, elbow_flexion=0.0)
    sol = solve_gamma(arm["S"], arm["W"], arm["R_tilt"], LU, LF)
    x_up = np.abs(arm["R_true"][:, 2, 0])  # vertical part of the arm's X axis
    elbow_error = np.linalg.norm(sol.p_world_elbow - arm["E"], axis=-1)
    gamma_error = np.abs(wrap(sol.gamma - arm["tau"]))
    v = arm["W"] - arm["S"]
    on_line = arm["S"] + LU * v / np.linalg.norm(v, axis=1, keepdims=True)
    print(f"\nstraight elbow, {n} arms: worst elbow {elbow_error.max():.1e} m, γ "
          f"{gamma_error.max():.1e} rad (smallest |X·up| {x_up.min():.1e}); all reachable "
          f"{sol.reachable.all()}, physiological {sol.physiological.all()}")
    assert sol.reachable.all() and sol.physiological.all()
    assert elbow_error.max() < 1e-9 and gamma_error.max() < 1e-9
    np.testing.assert_allclose(sol.p_world_elbow, on_line, atol=1e-9)

    # X axis horizontal (upright thorax, abduction and clavicle only), elbow straight:
    # a double root.
    abducted = random_arms(200, "right", seed=6, lean_deg=0.0, elbow_flexion=0.0,
                           shoulder_flexion=0.0, shoulder_rotation=0.0)
    sol = solve_gamma(abducted["S"], abducted["W"], abducted["R_tilt"], LU, LF)
    x_up = np.abs(abducted["R_true"][:, 2, 0])
    gamma_error = np.abs(wrap(sol.gamma - abducted["tau"]))
    elbow_error = np.linalg.norm(sol.p_world_elbow - abducted["E"], axis=-1)
    print(f"straight and X horizontal (|X·up| ≤ {x_up.max():.1e}): roots apart by "
          f"{np.abs(wrap(sol.gamma1 - sol.gamma2)).max():.1e} rad, γ error "
          f"{gamma_error.max():.1e} rad, elbow {elbow_error.max():.1e} m")
    assert sol.reachable.all()
    assert gamma_error.max() < 1e-6 and elbow_error.max() < 1e-7


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize(("pose", "angles"), [
    ("N-pose", {}), ("T-pose", {"shoulder_abduction": 90 * DEG}),
    ("T-pose, elbow flexed", {"shoulder_abduction": 90 * DEG, "elbow_flexion": 60 * DEG}),
])
def test_calibration_poses_are_degenerate(side, pose, angles):
    """Arm hanging (W - S vertical) or the X–Y plane horizontal: every heading keeps the
    wrist in the plane, so γ is NaN and flagged."""
    arm = forward_kinematics(angles, side, LENGTHS)
    S, W = (R_UPRIGHT @ arm.p_thorax[k] for k in ("shoulder", "wrist"))
    R = rot_z(0.3) @ R_UPRIGHT @ arm.R_thorax["upper_arm"]
    sol = solve_gamma(S, W, R, LU, LF)
    assert sol.degenerate and not sol.reachable, pose
    assert np.isnan(sol.gamma) and np.isnan(sol.p_world_elbow).all()
    turned = np.linspace(-np.pi, np.pi, 9)
    assert np.abs(plane_distance(turned, S, W, R)).max() < 1e-12  # any γ would do


def test_wrist_at_the_shoulder_is_degenerate():
    sol = solve_gamma(np.ones(3), np.ones(3), np.eye(3), LU, LF)
    assert sol.degenerate and np.isnan(sol.gamma)


# ---------------------------------------------------------------- out of reach
def test_out_of_reach_gives_nan_or_the_nearest_heading():
    rng = np.random.default_rng(9)
    n = 2000
    S = rng.uniform(-1, 1, (n, 3))
    W = S + rng.normal(size=(n, 3))
    R = Rotation.random(n, rng=rng).as_matrix()
    nz, vz = R[:, 2, 2], (W - S)[:, 2] / np.linalg.norm(W - S, axis=1)
    sol = solve_gamma(S, W, R, LU, LF)
    np.testing.assert_array_equal(sol.reachable, nz**2 + vz**2 <= 1)
    out = ~sol.reachable
    assert np.isnan(sol.gamma[out]).all() and np.isnan(sol.p_world_elbow[out]).all()

    near = solve_gamma(S, W, R, LU, LF, out_of_reach="nearest")
    np.testing.assert_array_equal(near.gamma[~out], sol.gamma[~out])
    assert not near.reachable[out].any()
    np.testing.assert_allclose(wrap(near.gamma1[out] - near.gamma2[out]), 0.0, atol=1e-12)
    grid = np.linspace(-np.pi, np.pi, 3601)
    dist_grid = np.abs(plane_distance(grid[None, :], S[out, None], W[out, None], R[out, None]))
    best = np.abs(plane_distance(near.gamma[out], S[out], W[out], R[out]))
    print(f"\n{out.sum()} of {n} random (S, W, R̃) out of reach (ñz² + v̂z² > 1)")
    assert (best <= dist_grid.min(axis=1) + 1e-12).all()


# ---------------------------------------------------------------- the seed as printed
def test_the_seed_as_printed_fails_and_all_four_corrections_are_needed():
    n = 2000
    arm = random_arms(n, "right", seed=21)
    truth = -arm["tau"]  # the seed's γ is about g = (0, 0, -1)
    names = ("fix_p", "fix_d", "fix_b", "fix_atan2")
    counts = {}
    for fixes in itertools.product((False, True), repeat=4):
        g1, g2 = seed_as_printed(arm["S"], arm["W"], arm["R_tilt"], **dict(zip(names, fixes,
                                                                               strict=True)))
        hit = (np.abs(wrap(g1 - truth)) < 1e-6) | (np.abs(wrap(g2 - truth)) < 1e-6)
        counts[fixes] = int(hit.sum())
    g1, g2 = seed_as_printed(arm["S"], arm["W"], arm["R_tilt"])
    either_sign = sum((np.abs(wrap(g - t)) < 1e-6) for g in (g1, g2)
                      for t in (truth, -truth)).astype(bool).sum()
    def row(fixes):
        marks = " ".join(f"{k[4:]:>5}" if f else "    -" for k, f in zip(names, fixes,
                                                                          strict=True))
        return f"  {marks}  {counts[fixes]:5d} / {n}"

    lines = [row(fixes) for fixes in counts]
    print(f"\nthe seed's γ on {n} exact arms (either root right; corrections applied):\n"
          + "\n".join(lines)
          + f"\nas printed, with either sign convention for γ: {either_sign} / {n}")
    assert counts[(False,) * 4] <= n // 100  # as printed: (almost) never
    assert counts[(True,) * 4] == n
    for i in range(4):  # every correction is needed: leave one out and many arms fail
        assert counts[tuple(j != i for j in range(4))] < 0.9 * n, names[i]


# ---------------------------------------------------------------- shapes and inputs
def test_single_samples_equal_the_batch_and_leading_shapes_broadcast():
    arm = random_arms(6, "left", seed=2)
    batch = solve_gamma(arm["S"], arm["W"], arm["R_tilt"], LU, LF)
    assert batch.gamma.shape == (6,) and batch.p_world_elbow.shape == (6, 3)
    assert batch.R_world_humerus.shape == (6, 3, 3) and batch.reachable.shape == (6,)
    for i in range(6):
        one = solve_gamma(arm["S"][i], arm["W"][i], arm["R_tilt"][i], LU, LF)
        assert one.gamma.shape == () and one.p_world_elbow.shape == (3,)
        assert one.gamma == batch.gamma[i] and one.gamma1 == batch.gamma1[i]
        np.testing.assert_array_equal(one.p_world_elbow, batch.p_world_elbow[i])
        np.testing.assert_array_equal(one.R_world_humerus, batch.R_world_humerus[i])
    grid = solve_gamma(arm["S"].reshape(2, 3, 3), arm["W"].reshape(2, 3, 3),
                       arm["R_tilt"].reshape(2, 3, 3, 3), LU, LF)
    np.testing.assert_array_equal(grid.gamma.ravel(), batch.gamma)
    fixed_shoulder = solve_gamma(arm["S"][0], arm["W"], arm["R_tilt"], LU, LF)
    assert fixed_shoulder.gamma.shape == (6,)


def test_nan_inputs_give_nan_without_warnings():
    arm = random_arms(4, "right", seed=4)
    S, W, R = arm["S"].copy(), arm["W"].copy(), arm["R_tilt"].copy()
    S[1, 0], W[2, 2], R[3, 1, 1] = np.nan, np.nan, np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sol = solve_gamma(S, W, R, LU, LF)
    assert np.isfinite(sol.gamma[0])
    assert np.isnan(sol.gamma[1:]).all() and np.isnan(sol.p_world_elbow[1:]).all()
    assert not sol.reachable[1:].any() and not sol.degenerate[1:].any()
    assert not sol.physiological[1:].any()


@pytest.mark.parametrize(("S", "W", "R"), [
    (np.zeros((5, 2)), np.zeros((5, 3)), np.tile(np.eye(3), (5, 1, 1))),
    (np.zeros((5, 3)), np.zeros((5, 4)), np.tile(np.eye(3), (5, 1, 1))),
    (np.zeros((5, 3)), np.zeros((5, 3)), np.zeros((5, 3, 4))),
    (np.zeros((5, 3)), np.zeros((4, 3)), np.tile(np.eye(3), (5, 1, 1))),
    (np.zeros(3), np.zeros(3), np.zeros(9)),
])
def test_bad_shapes_raise(S, W, R):
    with pytest.raises(InvalidShape, match="shape"):
        solve_gamma(S, W, R, LU, LF)


def test_bad_arguments_raise():
    S, W, R = np.zeros(3), np.ones(3), np.eye(3)
    with pytest.raises(InvalidArgument, match="upper_arm"):
        solve_gamma(S, W, R, -0.3, LF)
    with pytest.raises(InvalidArgument, match="forearm"):
        solve_gamma(S, W, R, LU, np.nan)
    with pytest.raises(InvalidArgument, match="out_of_reach"):
        solve_gamma(S, W, R, LU, LF, out_of_reach="clip")
    with pytest.raises(InvalidArgument, match="flexion_range"):
        solve_gamma(S, W, R, LU, LF, flexion_range=(1.0, 0.0))
