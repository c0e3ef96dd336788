r"""The elbow from the shoulder, the wrist and a heading-free upper-arm orientation: the
closed-form γ of the seed's Additional file 1 (``seeds/000_…``), derived again and corrected.

Known, in the world frame (z up, gravity ``(0, 0, -9.81)``):

- ``S`` shoulder centre and ``W`` wrist [m] (an end-effector robot or a camera gives ``W``);
- ``R̃ = R_world_humerus`` of the *upper-arm segment* (its sensor's orientation composed with
  the calibrated sensor-to-segment mounting) whose tilt is right — from the accelerometer —
  but whose heading about the vertical is unknown.

Sought: the heading correction ``γ`` [rad] with ``R(γ) = R_z(γ) R̃`` the true orientation,
then the elbow ``E = S + R(γ) (0, -l_u, 0)``.

Sign convention
---------------
``R_z(γ) = elemental("z", γ)``: ``γ`` is a right-handed rotation about world **+z (up)**,
applied on the world side (a change of heading, not of tilt). ``γ`` is returned wrapped to
``[-π, π)``. The seed measures its ``γ`` right-handed about its ``g = (0, 0, -1)`` (down): the
same rotation has ``γ_seed = -γ``.

Derivation, step by step
------------------------
1. The elbow flexes about the upper arm's Z axis, so the forearm, and with it the wrist
   (whatever the pronation), lies in the upper arm's X–Y plane through ``S``
   (``docs/spec/kinematics.md``: ``R_HF = Rz(flexion) Ry(pronation)``, the forearm runs along its
   own −Y). With the corrected orientation that plane is
   ``Π(γ) = {S + R(γ) (x, y, 0)}``, of unit normal ``n(γ) = R_z(γ) ñ``, ``ñ = R̃ e_z``.
2. The condition (the seed's eq. 1, corrected): the wrist's signed distance from ``Π(γ)`` is
   zero, ``d(γ) = n(γ) · (W - S) = 0``. Equivalently ``ñ · R_z(-γ) (W - S) = 0``: turning the
   wrist by ``-γ`` about the vertical through ``S`` instead of the plane by ``+γ`` (the
   seed's route, with its ``W̃``).
3. With ``v̂ = (W - S) / |W - S|`` and ``R_z(γ) ñ = (ñx c - ñy s, ñx s + ñy c, ñz)``
   (``c = cos γ``, ``s = sin γ``) the condition expands to::

       a cos γ - b sin γ + c = 0,
       a = ñx v̂x + ñy v̂y          (horizontal parts, dot product)
       b = ñy v̂x - ñx v̂y          (= (v̂ × ñ)_z, horizontal parts, cross product)
       c = ñz v̂z                  (the vertical parts; γ leaves them alone)

4. With ``m = √(a² + b²)`` and ``η = atan2(-b, a)`` (so ``a = m cos η``, ``-b = m sin η``, an
   identity, not an approximation) the condition is ``m cos(γ - η) = -c``, so with
   ``α = atan2(√(m² - c²), -c)`` (``cos α = -c/m``; atan2 keeps full accuracy where arccos
   loses it, near the double root)::

       γ1 = η - α,   γ2 = η + α.

   ``γ1`` is the seed's ``γ1``; the seed's ``γ2 = η - arccos(c/m) - π`` equals ``η + α - 2π``,
   the same angle.
5. Reach: a solution exists iff ``|c| ≤ m``. Since ``m = |ñ_h| |v̂_h| = √((1 - ñz²)(1 - v̂z²))``
   this is ``ñz² + v̂z² ≤ 1``: the shoulder-to-wrist line may not be steeper than the plane's
   steepest line. When it is (an inconsistent tilt or wrist: noise, a wrong mounting), no
   heading puts the wrist in the plane; ``out_of_reach="nan"`` gives NaN and
   ``reachable=False``, ``out_of_reach="nearest"`` gives the γ of least distance (then
   ``α = 0`` or ``π``, ``γ1 = γ2``), still with ``reachable=False``. At ``|c| = m`` the two
   roots merge (a double root, where γ is ill-conditioned: an error ε in the inputs moves γ by
   about ``√ε``).
6. Degenerate: ``m = 0`` (within ``degenerate_tolerance``) when ``W - S`` is vertical
   (``v̂_h = 0``: the wrist straight above or below the shoulder — the N-pose) or the plane's
   normal is vertical (``ñ_h = 0``: a horizontal arm plane — the T-pose), or ``W = S``. Then
   ``d(γ) = c`` for every γ: the wrist says nothing about the heading. γ, the elbow and the
   orientation are NaN, ``degenerate=True``; a tracker keeps its last heading there.

The seed's four corrections, each confirmed
-------------------------------------------
``tests/test_gamma.py`` implements the seed verbatim and with every subset of the four
corrections on random arms placed off the world origin, and prints how many recover the
true heading; only all four together do, and each one is confirmed by algebra too:

- **P̃ = S + R̃ e** (not ``R̃ e``): the seed's plane is the one through ``S``, ``P̃x``, ``P̃y``.
  With ``P̃ = R̃ e`` that plane passes through points near the world origin and its normal
  ``(R̃ e_y - S) × R̃ (e_y - e_x) = R̃ e_z - S × R̃ (e_y - e_x)`` is the arm's Z only when
  ``S = 0``. With ``P̃ = S + R̃ e``: ``N = R̃ e_y × R̃ (e_y - e_x) = R̃ (e_y × (e_y - e_x))
  = R̃ e_z = ñ``, exactly the unit normal of step 1. Confirmed.
- **D = -N·S**: the plane ``A x + B y + C z + D = 0`` must contain ``S``, so ``D = -N·S``.
  Then the seed's ``c = A Sx + B Sy + C (W̃z + Sz) + D`` (the point ``S + W̃`` tested against
  the plane) reduces to ``C W̃z = ñz v̂z``, step 3's ``c``. With ``+N·S`` it carries an extra
  ``2 N·S``. Confirmed.
- **b = A·W̃y − B·W̃x** (the seed has +): the γ-dependent part of ``N · R_z(γ) Ŵ`` is
  ``cos γ (A Ŵx + B Ŵy) - sin γ (A Ŵy - B Ŵx)`` — the seed's route, turning the wrist by
  ``+γ`` about z, i.e. by its ``γ_seed`` about ``g``; this is step 3 with ``γ → -γ``. In
  ``a`` and ``b`` the ``W̃`` must be read as ``Ŵ``, the wrist not yet turned (γ = 0).
  Confirmed.
- **atan2** for ``η``: ``arctan(-b/a)`` is off by π when ``a < 0`` (about half of all arms),
  which turns the equation into ``m cos(γ - η) = +c``; it also divides by zero at ``a = 0``.
  Confirmed.

The physiological choice of the two roots
-----------------------------------------
In the corrected upper-arm frame the wrist is ``w = R(γ)ᵀ (W - S) = (wx, wy, 0)`` with
``|w| = |W - S|`` and, since ``R_z`` leaves heights alone, ``u · w = (W - S)_z`` where
``u = R̃ᵀ e_z`` (world up in the arm frame, known from the tilt alone). A line meets a circle:
the two roots put the wrist at the two mirror images of each other across ``(ux, uy)``, the
in-plane up direction. The chain puts the wrist at
``w = (l_f sin φ, -l_u - l_f cos φ, 0)`` for elbow flexion ``φ`` — on a left arm too: the
mirror ``M Rz(φ) M = Rz(φ)`` keeps Z rotations, so although a left arm's Z points medially,
positive flexion still swings the forearm from −Y toward +X (anterior). So each root implies

- an elbow flexion ``φ_k = atan2(fx, -fy)`` of the forearm ``f = w - (0, -l_u, 0)``, and
- a forearm length ``|f| = |W - E_k|``.

The rule: **a root whose φ lies outside ``flexion_range`` (AAOS 0…150° widened by 10° for
hyperextension and noise) is rejected; of those left (or of both if neither is left), the
one whose |W − E| is nearest ``l_f`` is chosen.** Justification: the true root has
``|f| = l_f``; the mirror root has the same ``|f|`` only when ``ux = 0`` (the arm's X axis
horizontal), and then it is the mirror ``wx → -wx``, i.e. flexion ``-φ``, which the range
rejects unless ``|φ| < 10°`` (there both elbows are within ``2 l_f sin 10°`` of each other
and the choice is noise). ``physiological`` reports whether the chosen root's φ is in range.

The elbow fully straight (φ = 0): ``E, S, W`` are collinear, but the plane is not needed
from them — its tilt comes from ``R̃`` — so γ is still determined, and
``E = S + l_u (W - S)/|W - S|``. The two roots merge (and γ becomes ill-conditioned) exactly
when, in addition, the arm's X axis is horizontal; with the arm also vertical (the N-pose)
or the X–Y plane horizontal (the T-pose) the case is degenerate (step 6).

Assumptions: the forearm stays in the upper arm's X–Y plane (no carrying angle, as in the
spec's chain); ``R̃`` is a rotation matrix (not checked).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import InvalidArgument, InvalidShape
from ..rotations import elemental

#: Default accepted range of the implied elbow flexion [rad]: AAOS 0…150° widened by 10°.
FLEXION_RANGE = (np.deg2rad(-10.0), np.deg2rad(160.0))
#: Below this ``m = √(a² + b²)`` (unitless, of unit vectors) γ counts as undetermined.
DEGENERATE_TOLERANCE = 1e-9
#: ``|c| - m`` up to this (unitless) is still a (double) root, not out of reach: rounding.
REACH_TOLERANCE = 1e-12


@dataclass(frozen=True)
class GammaSolution:
    """The heading correction and the elbow; every array has the inputs' leading shape ``(...)``.

    ``gamma1``, ``gamma2``: the two roots [rad] in ``[-π, π)``, right-handed about world +z
    (NaN where degenerate or out of reach). ``gamma``: the chosen root [rad].
    ``p_world_elbow``: the elbow ``S + R_z(γ) R̃ (0, -l_u, 0)`` [m], shape ``(..., 3)``.
    ``R_world_humerus``: the corrected orientation ``R_z(γ) R̃``, shape ``(..., 3, 3)``.
    ``reachable``: a heading puts the wrist in the plane (``|c| ≤ m``). ``degenerate``: no
    heading is singled out (``m ≈ 0``). ``physiological``: the chosen root's implied elbow
    flexion is within the accepted range. ``elbow_flexion``: that implied flexion [rad].
    ``forearm_length_error``: ``|W - E| - l_f`` of the chosen root [m].
    """

    gamma1: np.ndarray
    gamma2: np.ndarray
    gamma: np.ndarray
    p_world_elbow: np.ndarray
    R_world_humerus: np.ndarray
    reachable: np.ndarray
    degenerate: np.ndarray
    physiological: np.ndarray
    elbow_flexion: np.ndarray
    forearm_length_error: np.ndarray


def _inputs(p_world_shoulder, p_world_wrist, R_world_humerus_tilt):
    S = np.asarray(p_world_shoulder, dtype=float)
    W = np.asarray(p_world_wrist, dtype=float)
    R = np.asarray(R_world_humerus_tilt, dtype=float)
    if S.shape[-1:] != (3,) or W.shape[-1:] != (3,):
        raise InvalidShape(
            f"shoulder and wrist must have shape (..., 3), got {S.shape} and {W.shape}")
    if R.shape[-2:] != (3, 3):
        raise InvalidShape(f"R_world_humerus must have shape (..., 3, 3), got {R.shape}")
    try:
        shape = np.broadcast_shapes(S.shape[:-1], W.shape[:-1], R.shape[:-2])
    except ValueError:
        raise InvalidShape(
            "shoulder (..., 3), wrist (..., 3) and R_world_humerus (..., 3, 3) need the same "
            f"leading shape, got {S.shape}, {W.shape} and {R.shape}") from None
    return (np.broadcast_to(S, (*shape, 3)), np.broadcast_to(W, (*shape, 3)),
            np.broadcast_to(R, (*shape, 3, 3)))


def gamma_coefficients(
    p_world_shoulder: np.ndarray, p_world_wrist: np.ndarray, R_world_humerus_tilt: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, c)`` of ``a cos γ - b sin γ + c = 0`` (module docstring, step 3), each ``(...)``.

    ``p_world_shoulder``, ``p_world_wrist``: ``S``, ``W`` [m], shape ``(..., 3)``;
    ``R_world_humerus_tilt``: ``R̃`` shape ``(..., 3, 3)``. Built from the unit vector
    ``(W - S)/|W - S|`` (zero where ``W = S``), so ``a``, ``b``, ``c`` are unitless.
    """
    S, W, R = _inputs(p_world_shoulder, p_world_wrist, R_world_humerus_tilt)
    v = W - S
    dist = np.linalg.norm(v, axis=-1, keepdims=True)
    v_hat = np.divide(v, dist, out=np.zeros_like(v), where=dist > 0)
    v_hat = np.where(np.isnan(dist), np.nan, v_hat)
    n = R[..., :, 2]
    a = n[..., 0] * v_hat[..., 0] + n[..., 1] * v_hat[..., 1]
    b = n[..., 1] * v_hat[..., 0] - n[..., 0] * v_hat[..., 1]
    c = n[..., 2] * v_hat[..., 2]
    return a, b, c


def gamma_roots(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    *,
    out_of_reach: Literal["nan", "nearest"] = "nan",
    degenerate_tolerance: float = DEGENERATE_TOLERANCE,
    reach_tolerance: float = REACH_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Both roots of ``a cos γ - b sin γ + c = 0`` (step 4), ``(γ1, γ2, reachable, degenerate)``.

    ``γ1 = η - α``, ``γ2 = η + α`` [rad] in ``[-π, π)``, ``η = atan2(-b, a)``,
    ``α = atan2(√(m² - c²), -c)``. Out of reach (``|c| > m``): NaN, or with
    ``out_of_reach="nearest"`` the γ that minimises ``|a cos γ - b sin γ + c|`` in both.
    Degenerate (``m ≤ degenerate_tolerance``): NaN. NaN in → NaN out, both flags False.
    """
    if out_of_reach not in ("nan", "nearest"):
        raise InvalidArgument(f"out_of_reach must be 'nan' or 'nearest', got {out_of_reach!r}")
    a, b, c = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (a, b, c)))
    m = np.hypot(a, b)
    degenerate = m <= degenerate_tolerance
    reachable = (np.abs(c) <= m + reach_tolerance) & ~degenerate
    eta = np.arctan2(-b, a)
    alpha = np.arctan2(np.sqrt(np.maximum(m * m - c * c, 0.0)), -c)
    keep = reachable | (~degenerate & (out_of_reach == "nearest"))
    keep = keep & np.isfinite(m) & np.isfinite(c)
    gamma1 = np.where(keep, _wrap(eta - alpha), np.nan)
    gamma2 = np.where(keep, _wrap(eta + alpha), np.nan)
    return gamma1, gamma2, reachable, degenerate


def solve_gamma(
    p_world_shoulder: np.ndarray,
    p_world_wrist: np.ndarray,
    R_world_humerus_tilt: np.ndarray,
    upper_arm: float,
    forearm: float,
    *,
    flexion_range: tuple[float, float] = FLEXION_RANGE,
    out_of_reach: Literal["nan", "nearest"] = "nan",
    degenerate_tolerance: float = DEGENERATE_TOLERANCE,
    reach_tolerance: float = REACH_TOLERANCE,
) -> GammaSolution:
    """The heading correction γ, the elbow and the corrected upper-arm orientation.

    ``p_world_shoulder``, ``p_world_wrist``: ``S``, ``W`` [m], shape ``(..., 3)`` (e.g.
    ``(N, 3)`` over time, or ``(3,)``). ``R_world_humerus_tilt``: ``R̃``, the upper-arm
    segment's orientation with the right tilt and any heading, shape ``(..., 3, 3)``.
    ``upper_arm``, ``forearm``: ``l_u``, ``l_f`` [m]. ``flexion_range``: accepted implied
    elbow flexion [rad]. Either arm side (the rule is the same, see the module docstring).
    Returns a :class:`GammaSolution` with leading shape ``(...)``.
    """
    for name, length in (("upper_arm", upper_arm), ("forearm", forearm)):
        if not (np.ndim(length) == 0 and np.isfinite(length) and length > 0):
            raise InvalidArgument(f"{name} must be a finite length > 0 m, got {length!r}")
    lo, hi = flexion_range
    if not lo < hi:
        raise InvalidArgument(f"flexion_range must be (low, high) with low < high, got "
                              f"{flexion_range!r}")
    S, W, R = _inputs(p_world_shoulder, p_world_wrist, R_world_humerus_tilt)
    a, b, c = gamma_coefficients(S, W, R)
    gamma1, gamma2, reachable, degenerate = gamma_roots(
        a, b, c, out_of_reach=out_of_reach, degenerate_tolerance=degenerate_tolerance,
        reach_tolerance=reach_tolerance)
    # A NaN anywhere in a sample (even in R̃'s X or Y column, which γ does not use) voids it.
    finite = np.isfinite(S).all(-1) & np.isfinite(W).all(-1) & np.isfinite(R).all((-2, -1))
    gamma1, gamma2 = np.where(finite, gamma1, np.nan), np.where(finite, gamma2, np.nan)
    reachable, degenerate = reachable & finite, degenerate & finite

    # Both candidates side by side on a trailing axis of 2.
    gammas = np.stack([gamma1, gamma2], axis=-1)
    R_k = elemental("z", gammas) @ R[..., None, :, :]
    R_k = np.where(np.isnan(gammas)[..., None, None], np.nan, R_k)  # R_z(NaN) keeps z finite
    w = np.einsum("...ji,...j->...i", R_k, (W - S)[..., None, :])
    fx, fy = w[..., 0], w[..., 1] + upper_arm
    flexion = np.arctan2(fx, -fy)
    length_error = np.hypot(fx, fy) - forearm
    ok = (flexion >= lo) & (flexion <= hi)
    err = np.abs(length_error)
    second = (ok[..., 1] & ~ok[..., 0]) | ((ok[..., 1] == ok[..., 0]) & (err[..., 1] < err[..., 0]))

    def pick(x):  # the chosen candidate of x, shape (..., 2, *tail) -> (..., *tail)
        axis = second.ndim
        chosen = second.reshape(second.shape + (1,) * (x.ndim - axis - 1))
        return np.where(chosen, np.take(x, 1, axis=axis), np.take(x, 0, axis=axis))

    R_chosen = pick(R_k)
    elbow = S - upper_arm * R_chosen[..., :, 1]
    return GammaSolution(
        gamma1=gamma1, gamma2=gamma2, gamma=pick(gammas), p_world_elbow=elbow,
        R_world_humerus=R_chosen, reachable=reachable, degenerate=degenerate,
        physiological=pick(ok), elbow_flexion=pick(flexion),
        forearm_length_error=pick(length_error))


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles [rad] to ``[-π, π)``."""
    return (angle + np.pi) % (2 * np.pi) - np.pi
