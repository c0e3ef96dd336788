"""Calibration of a session from its sensors' tracks: sensor-to-segment rotations, the
thorax's heading, and (6-axis kits) the headings that put every sensor in one world.

Order: arm sensors first (two-pose, N-pose-only or default mounting; with a trunk sensor,
each pose's up direction is the thorax's, not gravity's, so a trunk that sways through the
poses does not tilt the arm's axes by the sway's mean, and the thorax's upright, the
centre of the trunk's sway over the poses (``_sway_centre``), is made square to the axis
the arm turned about between them relative to the trunk, so a slow sway's lean left in
that centre does not turn the arm's axes about the vertical); then the world thorax in the
N-pose from the arm (every segment's axes are the thorax's there); then the trunk and
clavicle sensors' headings from it. On a 6-axis kit each sensor's filter has a heading of
its own: in the N-pose all segments point the same way, which gives each sensor the turn
about the vertical that brings it into the reference sensor's world; there a clavicle
sensor's own turn about the vertical is the default mounting's (no shared heading makes it
observable), so the thorax is right in the N-pose and a sensor mounted turned mixes
forward and sideways bending by that turn. A 6-axis trunk sensor with two poses is
calibrated twice: the first pass's headings put the filters in one world for the sway's
corrections above, and the trunk's turn between its world and the arm's comes from the
held poses' sway (arm and trunk turn as one, ``_gyro_heading``), weighed against the
default mounting's.
With no pose at all (default mounting) the first second of the recording stands in for
the N-pose: the patient is taken to start with the arm hanging.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import sici
from scipy.stats import chi2

from ..body import Side
from ..calibration import (
    CalibrationPlan,
    CalibrationWarning,
    default_R_segment_sensor,
    heading_from_arm,
    pose_stillness_warnings,
    tilt_only_R_sensor_segment,
    turn_warning,
    two_pose_R_sensor_segment,
)
from ..calibration.quality import TPOSE_TURN_DEG, trunk_sway_warning
from ..rotations import quat_to_matrix, yaw_of
from .segment_kernel import segment_orientations
from .tracks import SensorTrack

ARM = ("upper_arm", "forearm", "hand")
#: How well the arm's turn between the poses, relative to the trunk sensor, gives the
#: thorax's X [rad], by kit (True: 9-axis): the filters' relative orientation N → T. With
#: every arm filter restarted from the poses' biases, the 9-axis kits' forward lean after
#: the correction was off by 0.34° where 0.5° was said (random/irregular/sine sway seeds
#: 1–10: normalised squared error 0.46 a kit; ``test_the_uprights_lean_is_as_sure_as_it_says``);
#: with the trunk's filter restarted from its whole pose bias too, 0.30° where 0.35° was
#: said (the same seeds: 0.74 a kit; held out 11–20 0.23°); 6-axis kits' axes are worse
#: (the same with 0.5°: 1.10 tuning, 2.35 held out).
AXIS_SIGMA_RAD = {True: np.deg2rad(0.30), False: np.deg2rad(0.5)}
#: How far a 6-axis trunk sensor may sit turned about the thorax's long axis from the
#: kit's guide (its default mounting), as one σ [rad]: the prior the sway's gyroscopes
#: are weighed against (``_gyro_heading``).
TRUNK_TURN_SIGMA_RAD = np.deg2rad(15.0)


@dataclass(frozen=True)
class Calibration:
    """The result: ``method`` (two-pose, n-pose, default), ``final_time_s``;
    ``R_sensor_segment`` per sensor; ``heading`` per sensor [rad], the turn about the
    vertical applied to its world (0 with a magnetometer); ``R_world_thorax`` the fixed
    thorax when there is no trunk sensor; ``warnings``. A segment's orientation is
    ``Rz(heading) · R_world_sensor · R_sensor_segment`` (``segment_kernel``).
    ``lean_sd_deg``: how well the thorax's upright is known through a trunk's sway, one σ
    of its side lean (about the thorax's X) and forward lean (about its Z) [deg]; None
    when the upright is not the sway's centre (no trunk sensor, no poses);
    ``lean_basis``: what that σ was made of (``LeanBasis``), for the session to tell it
    again from how the trunk sways through it (``sway.retold_lean``)."""

    method: str
    final_time_s: float
    R_sensor_segment: dict[str, np.ndarray]
    heading: dict[str, float]
    R_world_thorax: np.ndarray
    warnings: tuple[CalibrationWarning, ...]
    lean_sd_deg: tuple[float, float] | None = None
    lean_basis: LeanBasis | None = None


@dataclass(frozen=True)
class LeanBasis:
    """How the calibration's thorax upright was taken through a trunk's sway: the poses'
    span ``start``…``end`` [s] the sway's centre was fitted over (``_sway_centre``), the
    thorax's ``lateral`` (Z) and ``forward`` (X) axes in the trunk sensor's frame (unit),
    that centre's error covariance ``up_covariance`` [rad², sensor frame], the share
    ``axis_weight`` of its forward part the abduction axis replaced and that axis's
    variance ``axis_var`` [rad²], and ``nine_axis`` (the warning's level)."""

    start: float
    end: float
    lateral: np.ndarray
    forward: np.ndarray
    up_covariance: np.ndarray
    axis_weight: float
    axis_var: float
    nine_axis: bool

    def lean_sd_deg(self, side_scale: float = 1.0, forward_scale: float = 1.0
                    ) -> tuple[float, float]:
        """One σ of the side and forward lean [deg], the centre's variance along each
        axis scaled by ``side_scale`` and ``forward_scale`` (what a session showed of the
        sway's centre against what its model told, ``sway.retold_lean``; 1: as told)."""
        side_var = side_scale * float(self.lateral @ self.up_covariance @ self.lateral)
        forward_var = ((1.0 - self.axis_weight) ** 2 * forward_scale
                       * float(self.forward @ self.up_covariance @ self.forward)
                       + self.axis_weight**2 * self.axis_var)
        return float(np.rad2deg(np.sqrt(side_var))), float(np.rad2deg(np.sqrt(forward_var)))


def _up(acc: np.ndarray) -> np.ndarray:
    mean = acc.mean(axis=0)
    return mean / np.linalg.norm(mean)


def _mean_rotation(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q, scalar_first=True).mean().as_matrix()


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _thorax_up(arm: SensorTrack, trunk: SensorTrack, start: float, end: float,
               trunk_up: np.ndarray, turn: float = 0.0) -> np.ndarray:
    """The thorax's up direction in an arm sensor's frame over ``start…end``, averaged:
    the arm's gravity plus the trunk's momentary tilt away from its upright ``trunk_up``
    (trunk sensor frame), carried into the arm sensor's frame through the two sensors'
    orientations at the arm's sample times (the trunk's world turned by ``turn`` [rad]
    about the vertical into the arm's: 6-axis filters each have a heading of their own).
    Both directions are the accelerometers'; the orientations only turn the small tilt, so
    their errors count to second order."""
    t, acc, _, q = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t, acc, q = t[a:b], acc[a:b], q[a:b]
    t_trunk, acc_trunk, _, q_trunk = trunk.arrays()
    gravity_trunk = _unit_rows(np.stack([np.interp(t, t_trunk, acc_trunk[:, k])
                                         for k in range(3)], axis=1))
    R_trunk = segment_orientations(t_trunk, q_trunk, t, np.eye(3), turn)
    tilt_world = np.einsum("nij,nj->ni", R_trunk, trunk_up - gravity_trunk)
    tilt_arm = np.einsum("nji,nj->ni", quat_to_matrix(q), tilt_world)
    return _up(_unit_rows(acc) + tilt_arm)


def _relative(arm: SensorTrack, trunk: SensorTrack, start: float, end: float,
              turn: float = 0.0) -> np.ndarray | None:
    """The arm sensor's axes in the trunk sensor's frame, ``R_trunk_arm``, averaged over
    ``start…end`` at the arm's sample times (None without samples), the trunk's world
    turned by ``turn`` [rad] into the arm's: a sway that turns both sensors alike drops
    out."""
    t, _, _, q = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t_trunk, _, _, q_trunk = trunk.arrays()
    if b <= a or not len(t_trunk):
        return None
    R_trunk = segment_orientations(t_trunk, q_trunk, t[a:b], np.eye(3), turn)
    return Rotation.from_matrix(np.einsum("nji,njk->nik", R_trunk, quat_to_matrix(q[a:b]))
                                ).mean().as_matrix()


def _abduction_axis(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan,
                    turns: Mapping[str, float]) -> np.ndarray | None:
    """The axis (unit, trunk sensor frame) about which the arm turned from the N-pose to
    the T-pose relative to the trunk sensor, mean over the arm's sensors: the thorax's X.
    None when a window is empty or an arm sensor did not turn like a T-pose. ``turns``:
    per arm sensor, the turn [rad] of the trunk's world into its own (see ``_thorax_up``)."""
    assert plan.npose is not None and plan.tpose is not None
    axes = []
    for sensor in (s for s in ARM if s in tracks):
        n = _relative(tracks[sensor], tracks["trunk"], plan.npose.start, plan.npose.end,
                      turns[sensor])
        t = _relative(tracks[sensor], tracks["trunk"], plan.tpose.start, plan.tpose.end,
                      turns[sensor])
        if n is None or t is None:
            return None
        turn = Rotation.from_matrix(t @ n.T).as_rotvec()
        angle = np.linalg.norm(turn)
        lo, hi = TPOSE_TURN_DEG
        if not lo <= np.rad2deg(angle) <= hi:
            return None
        axis = turn / angle
        axes.append(axis if not axes or axis @ axes[0] > 0 else -axis)
    if not axes:
        return None
    mean = np.mean(axes, axis=0)
    return mean / np.linalg.norm(mean)


def _gyro_heading(arm: SensorTrack, trunk: SensorTrack, start: float, end: float
                  ) -> tuple[float, float] | None:
    """The turn about the vertical [rad] that takes the trunk's 6-axis filter world into
    the arm sensor's, and its σ [rad], from a held pose ``start…end``: the arm held still
    on the body turns with the trunk as one (a sway), so the two gyroscopes read one
    rotation (``_rigid_fit``); the σ is the fit's about the trunk's vertical. None without
    a pose's worth of samples, or when the rates showed no turn about the vertical."""
    fit = _rigid_fit(arm, trunk, start, end)
    if fit is None:
        return None
    C, _, _, covariance, _ = fit
    t, _, _, q = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t_trunk, _, _, q_trunk = trunk.arrays()
    R_trunk = segment_orientations(t_trunk, q_trunk, t[a:b], np.eye(3), 0.0)
    vertical = R_trunk[:, 2, :].mean(axis=0)  # the world's vertical in the trunk's frame
    vertical /= np.linalg.norm(vertical)
    sigma = float(np.sqrt(vertical @ covariance @ vertical))
    if not np.isfinite(sigma):  # no turn about the vertical seen (a still pose)
        return None
    turn = quat_to_matrix(q[a:b]) @ C.T @ np.transpose(R_trunk, (0, 2, 1))  # Rz per sample
    return float(yaw_of(Rotation.from_matrix(turn).mean().as_matrix())), sigma


#: A gyroscope's bias as one σ [rad/s] before anything is learnt (a MEMS zero-rate offset;
#: ``QcfParams.bias_sigma``): the prior of ``biases_from_poses``.
BIAS_SIGMA = 0.01
#: The finest step a kit's readings come in, as the floor of every variance the held poses'
#: fits take from them: a gyroscope's [rad/s] (16 bits over ±125 °/s) and an accelerometer's
#: direction [rad] (16 bits over ±2 g). Readings whose noise that step hides (a still kit,
#: a simulation without noise) show none, and a variance floored near 0 made the fits'
#: information 1e30 beside the prior's 1e4: a negative variance, σ NaN, the estimation
#: stopped (``test_a_noiseless_still_kit_has_finite_pose_biases``). Any real noise is above.
GYRO_STEP = np.deg2rad(250.0 / 2**16)
TILT_STEP = 4.0 / 2**16
#: The variance of a rounding to such a step: step² / 12.
GYRO_STEP_VARIANCE = GYRO_STEP**2 / 12.0
TILT_STEP_VARIANCE = TILT_STEP**2 / 12.0
#: How much more the rigid fit's first guess weighs the two mean gravities than the rates
#: (both unit-normed): gravity held exactly, the rates give the turn about it.
GRAVITY_FIRST = 1e3
#: Half the span [s] of the line fitted through a held pose's rates for their derivative,
#: the angular acceleration that moves a sensor held off the sway's pivot (``_tilt_bias``):
#: a sway of ≤ 0.5 Hz is a line over 0.5 s, the gyroscope's noise averaged over ~25 samples.
LEVER_HALF_S = 0.25


def _skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrices ``[v]×`` of vectors ``v`` (..., 3): ``[v]× u = v × u``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _local_slope(t: np.ndarray, x: np.ndarray, half: float) -> np.ndarray:
    """``dx/dt`` at each sample ``t`` [s] of ``x`` (N, k): the least-squares line through
    the samples within ±``half`` [s] (fewer at the ends), any sampling."""
    a = np.searchsorted(t, t - half, "left")
    b = np.searchsorted(t, t + half, "right")
    s = t - t[0]

    def sums(v: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros((1, *v.shape[1:])), np.cumsum(v, axis=0)])

    count = (b - a).astype(np.float64)
    st, stt, sx, stx = sums(s), sums(s * s), sums(x), sums(s[:, None] * x)
    mean_t = (st[b] - st[a]) / count
    var_t = (stt[b] - stt[a]) / count - mean_t**2
    mean_x = (sx[b] - sx[a]) / count[:, None]
    cov_tx = (stx[b] - stx[a]) / count[:, None] - mean_t[:, None] * mean_x
    return cov_tx / np.maximum(var_t, 1e-12)[:, None]


def _rigid_fit(arm: SensorTrack, trunk: SensorTrack, start: float, end: float):
    """The held pose ``start…end`` as one rigid turn of arm and trunk: the two gyroscopes
    read one rotation, ``ω_trunk = C ω_arm`` with ``C = R_trunk_arm``, fitted to the rates
    less their means (which hold each sensor's bias), and the two accelerometers one
    gravity, ``g_trunk = C g_arm`` (their means, unit): a sway turns about a horizontal
    axis, which leaves the rates blind about it, and gravity sees every turn but the one
    about the vertical, which the rates see. Each is weighed by its own scatter about the
    fit (the gravity's not averaged down: the two sensors' levers from the sway's pivot
    differ, an error that does not average out over a pose). Returns ``(C, d, σ_d, Σ_C,
    v)``: ``d`` the mean of ``ω_trunk − C ω_arm`` (= ``b_trunk − C b_arm`` [rad/s]), its
    σ per axis, ``Σ_C`` the covariance of ``C``'s turn error (trunk frame, [rad²]) and
    ``v = C ω̄_arm``, through which that error enters ``d``; None without a pose's worth
    of samples."""
    t, acc, gyr, _ = arm.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    t_trunk, acc_trunk, gyr_trunk, _ = trunk.arrays()
    if b - a < 10 or len(t_trunk) < 2:
        return None
    w_arm = gyr[a:b]
    w_trunk = np.stack([np.interp(t[a:b], t_trunk, gyr_trunk[:, k]) for k in range(3)],
                       axis=1)
    g_arm = _unit_rows(acc[a:b])
    g_trunk = _unit_rows(np.stack([np.interp(t[a:b], t_trunk, acc_trunk[:, k])
                                   for k in range(3)], axis=1))
    mean_arm, mean_trunk = _up(g_arm), _up(g_trunk)
    c_arm, c_trunk = w_arm - w_arm.mean(axis=0), w_trunk - w_trunk.mean(axis=0)
    # Start from gravity held exactly and the rates for the turn about it: started from the
    # rates alone (blind about the sway's axis), a wrong turn there made gravity's scatter
    # about the fit large, its weight small, and the fit stayed wrong (up to 124° off with
    # a σ of 5°: sine sway seed 10's N-pose).
    cross = c_arm.T @ c_trunk
    C = _kabsch(cross / max(float(np.linalg.norm(cross)), 1e-30)
                + GRAVITY_FIRST * np.outer(mean_arm, mean_trunk))
    for _ in range(2):  # each part weighed by its scatter about the last fit
        residual = w_trunk - w_arm @ C.T
        d = residual.mean(axis=0)
        variance = max(float(np.mean(np.sum((residual - d) ** 2, axis=1)) / 3.0),
                       2.0 * GYRO_STEP_VARIANCE)
        gravity_variance = max(float(np.mean(np.sum((g_trunk - g_arm @ C.T) ** 2,
                                                    axis=1))), 1e-12)
        C = _kabsch(c_arm.T @ c_trunk / variance
                    + np.outer(mean_arm, mean_trunk) / gravity_variance)
    residual = w_trunk - w_arm @ C.T
    d = residual.mean(axis=0)
    variance = max(float(np.mean(np.sum((residual - d) ** 2, axis=1)) / 3.0),
                   2.0 * GYRO_STEP_VARIANCE)
    spread = c_trunk.T @ c_trunk
    information = (np.trace(spread) * np.eye(3) - spread) / variance \
        + (np.eye(3) - np.outer(mean_trunk, mean_trunk)) / gravity_variance
    # a turn the fit cannot see (rates without a turn, a still pose): infinite variances,
    # no NaN of 0 · inf off the diagonal
    covariance = np.linalg.pinv(information) if np.linalg.det(information) > 0 else \
        np.diag(np.full(3, np.inf))
    return C, d, np.sqrt(variance / (b - a)), covariance, C @ w_arm.mean(axis=0)


def _tilt_bias(track: SensorTrack, start: float, end: float):
    """The gyroscope bias across gravity a held pose ``start…end`` shows [rad/s] (sensor
    frame), as information and evidence: the gyroscope's turn, integrated, must keep the
    accelerometer's direction; what it drifts from it by, linearly in time, is the bias
    (small turns: a held pose only sways). The sway moves the sensor too: held on a body
    that turns about a fixed pivot, it accelerates by ``a = α × r + ω × (ω × r)`` (sensor
    frame; ``r`` the pivot-to-sensor lever, ``α`` the rates' slope), which tilts the
    accelerometer's direction slowly, alike for seconds: a quarter of a slow sway's cycle
    looks like drift (the bias 7.4 mrad/s RMS off while its σ said 2.1; arm sensors in the
    T-pose, far from the pivot, up to 22). ``r`` is fitted beside the bias, and the bias's
    information is what is left once ``r`` is free (2.4 mrad/s off, σ 4.5). The residual's
    noise is counted over the samples it is correlated across. Returns ``(information,
    evidence, t, residual)``, the last the fit's residual direction (N, 3; sensor frame) at
    the pose's sample times ``t`` [s]; None without a pose's worth of samples."""
    t, acc, gyr, _ = track.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    if b - a < 10:
        return None
    t, acc, gyr = t[a:b], acc[a:b], gyr[a:b]
    unit = _unit_rows(acc)
    g = _up(unit)
    from scipy.integrate import cumulative_trapezoid  # here: scipy.integrate is slow to import

    turned = cumulative_trapezoid(gyr, t, axis=0, initial=0.0)
    y = unit + np.cross(turned, g)
    y -= y.mean(axis=0)
    tc = t - t.mean()
    # the design: the bias's drift, −t [g]× b, and the sway's acceleration across gravity
    # over its norm, (I − g gᵀ)([α]× + [ω]×[ω]×) r / |f| (each less its mean)
    skew_w = _skew(gyr)
    lever = np.einsum("ij,njk->nik", np.eye(3) - np.outer(g, g),
                      _skew(_local_slope(t, gyr, LEVER_HALF_S)) + skew_w @ skew_w)
    lever = (lever - lever.mean(axis=0)) / float(np.mean(np.linalg.norm(acc, axis=1)))
    design = np.concatenate([-tc[:, None, None] * _skew(g)[None], lever], axis=2)
    design = design.reshape(-1, 6)
    normal, moment = design.T @ design, design.T @ y.reshape(-1)
    solution = np.linalg.lstsq(normal, moment, rcond=None)[0]
    res = y - (design @ solution).reshape(-1, 3)
    variance = max(float(np.mean(np.sum(res**2, axis=1))) / 2.0, TILT_STEP_VARIANCE)
    r = res - res.mean(axis=0)
    rho = float(np.sum(r[1:] * r[:-1]) / max(float(np.sum(r * r)), 1e-30))
    rho = min(max(rho, 0.0), 0.999)
    variance *= (1.0 + rho) / (1.0 - rho)  # an AR(1) residual's effective sample count
    # the bias's part once the lever is free (its Schur complement)
    gain = normal[:3, 3:] @ np.linalg.pinv(normal[3:, 3:])
    info = normal[:3, :3] - gain @ normal[3:, :3]
    ev = moment[:3] - gain @ moment[3:]
    return info / variance, ev / variance, t, res


#: The blocks [s] the tilt drifts' residuals are averaged over before their correlation
#: from sensor to sensor is taken (``_common_share``): the accelerometers' white noise
#: averages out, the sway's slow error (its period 2–20 s) stays.
DRIFT_BLOCK_S = 0.5


def _common_share(tilts: Mapping[str, tuple | None], turns: Mapping[str, np.ndarray]
                  ) -> float:
    """ρ ∈ [0, 1]: the mean correlation, from sensor to sensor, of the tilt drifts'
    residuals (``_tilt_bias``) over one held pose, each turned into the trunk sensor's frame
    (``turns``: per arm sensor ``R_trunk_arm``), at the trunk's sample times, averaged over
    ``DRIFT_BLOCK_S`` blocks. 0 with fewer than two."""
    trunk = tilts.get("trunk")
    if trunk is None:
        return 0.0
    t0 = trunk[2]
    series = [trunk[3]]
    for sensor, C in turns.items():
        tilt = tilts.get(sensor)
        if tilt is not None:
            turned = tilt[3] @ C.T
            series.append(np.stack([np.interp(t0, tilt[2], turned[:, k]) for k in range(3)],
                                   axis=1))
    block = np.floor((t0 - t0[0]) / DRIFT_BLOCK_S).astype(int)
    count = np.bincount(block)
    kept = count > 0  # (a gap in the samples leaves a block empty)
    means = []
    for r in series:
        m = np.stack([np.bincount(block, r[:, k])[kept] for k in range(3)], axis=1) \
            / count[kept, None]
        means.append(m - m.mean(axis=0))
    pairs = [float(np.sum(a * b) / max(np.sqrt(np.sum(a * a) * np.sum(b * b)), 1e-30))
             for j, a in enumerate(means) for b in means[j + 1:]]
    return float(np.clip(np.mean(pairs), 0.0, 1.0)) if pairs else 0.0


def _white_variance(track: SensorTrack, start: float, end: float) -> float:
    """The variance [rad²/s²] of the mean over ``start…end`` of a gyroscope's white noise
    per axis: its variance from the rates' second differences (``ω[i+1] − 2ω[i] + ω[i−1]``
    holds 6σ² of white noise, next to nothing of a slow turn; at least ``GYRO_STEP``'s
    rounding), over the samples' count."""
    t, _, gyr, _ = track.arrays()
    a, b = np.searchsorted(t, start, "left"), np.searchsorted(t, end, "right")
    if b - a < 3:
        return GYRO_STEP_VARIANCE
    second = gyr[a + 2: b] - 2.0 * gyr[a + 1: b - 1] + gyr[a: b - 2]
    return max(float(np.mean(second**2)) / 6.0, GYRO_STEP_VARIANCE) / (b - a)


def _kabsch(cross: np.ndarray) -> np.ndarray:
    """The rotation ``C`` that best turns the first vectors into the second given their
    weighed cross sum ``Σ w a bᵀ`` (Kabsch)."""
    u, _, vt = np.linalg.svd(cross)
    return vt.T @ np.diag([1.0, 1.0, np.linalg.det(vt.T @ u.T)]) @ u.T


@dataclass(frozen=True)
class PoseBiases:
    """The gyroscope biases the held poses show on a kit with a trunk sensor
    (``biases_from_poses``): ``vertical`` the trunk's bias about the vertical [rad/s],
    ``up`` that vertical (unit, trunk sensor frame), ``sigma`` its standard error [rad/s];
    ``trunk`` the trunk's whole bias and ``arm`` per arm sensor, each ``(bias [rad/s],
    covariance [rad²/s²])``, sensor frame."""

    vertical: float
    up: np.ndarray
    sigma: float
    arm: dict[str, tuple[np.ndarray, np.ndarray]]
    trunk: tuple[np.ndarray, np.ndarray]


def biases_from_poses(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan,
                      priors: Mapping[str, np.ndarray] | None = None) -> PoseBiases | None:
    """A trunk sensor's gyroscope bias about the vertical, and the arm sensors'
    biases, from the held N- and T-poses (``PoseBiases``). In each pose the arm turns with
    the trunk as one (a sway), so every sample gives ``ω_trunk − C ω_arm = b_trunk −
    C b_arm`` with ``C = R_trunk_arm`` fitted to the rates and gravity (``_rigid_fit``);
    two poses that differ by the arm's turn about the thorax's X tell ``b_trunk`` apart
    from the arm's biases but along that axis, which is horizontal in both poses: there
    each sensor's own tilt drift over the pose shows its bias (``_tilt_bias``). The
    trunk's vertical part is what the tilt never sees on a trunk that only sways; the
    arm's are what its tilt windows learn only slowly in motion (the arm's own
    accelerations hide them; no sensor of a swaying kit rests). Least squares over every
    sensor and both poses with the prior ``BIAS_SIGMA`` on every bias; what each pose
    shows of a gyroscope is its mean, the bias plus its white noise averaged over the
    pose (one unknown per sensor and pose, its variance from the rates' second
    differences, in every fit of that gyroscope: counted once, not once per fit); each
    rigid fit weighed by what else is in its residual and by ``C``'s error; the tilt
    drifts, whose sway errors are one from sensor to sensor, by their effective count
    (``_common_share``). ``priors``: a sensor's bias known before (a remembered one
    [rad/s], sensor frame; else 0) as that prior's mean. None without two poses."""
    if plan.npose is None or plan.tpose is None or "trunk" not in tracks:
        return None
    arms = [s for s in ARM if s in tracks]
    if not arms:
        return None
    sensors = ["trunk", *arms]
    poses = (plan.npose, plan.tpose)
    n = len(sensors)
    # the unknowns: each sensor's bias b_i, then each gyroscope's noise averaged over each
    # pose, u_ip: a pose shows a gyroscope's mean, b_i + u_ip, never b_i alone, to every
    # fit that uses that gyroscope (its tilt drift and each rigid fit it is in)
    size = 3 * n * (1 + len(poses))

    def bias(i: int) -> slice:
        return slice(3 * i, 3 * i + 3)

    def mean_noise(i: int, p: int) -> slice:
        return slice(3 * n * (1 + p) + 3 * i, 3 * n * (1 + p) + 3 * i + 3)

    information = np.zeros((size, size))
    evidence = np.zeros(size)
    for i, sensor in enumerate(sensors):
        information[bias(i), bias(i)] = np.eye(3) / BIAS_SIGMA**2
        if priors is not None and sensor in priors:
            evidence[bias(i)] = np.asarray(priors[sensor], dtype=np.float64) / BIAS_SIGMA**2
        for p, pose in enumerate(poses):
            information[mean_noise(i, p), mean_noise(i, p)] = np.eye(3) / _white_variance(
                tracks[sensor], pose.start, pose.end)
    for p, pose in enumerate(poses):
        turns = {}
        for k, sensor in enumerate(arms, start=1):
            fit = _rigid_fit(tracks[sensor], tracks["trunk"], pose.start, pose.end)
            if fit is None:
                return None
            C, d, sigma_d, covariance, v = fit
            turns[sensor] = C
            row = np.zeros((3, size))
            row[:, bias(0)] = row[:, mean_noise(0, p)] = np.eye(3)
            row[:, bias(k)] = row[:, mean_noise(k, p)] = -C
            # the residual's scatter less the gyroscopes' white noise (now in u), and C's
            # turn error ε, which moves d by ε × v
            white = _white_variance(tracks["trunk"], pose.start, pose.end) + \
                _white_variance(tracks[sensor], pose.start, pose.end)
            noise = (max(sigma_d**2 - white, 0.0) + 1e-12) * np.eye(3) + _skew(
                v) @ np.nan_to_num(covariance, posinf=1e6) @ _skew(v).T
            weight = np.linalg.inv(noise)
            information += row.T @ weight @ row
            evidence += row.T @ weight @ d
        tilts = {sensor: _tilt_bias(tracks[sensor], pose.start, pose.end)
                 for sensor in sensors}
        # the sway's acceleration, as far as the lever leaves it, is one error in every
        # sensor's tilt drift (they turn as one): the drifts' residuals, averaged over
        # DRIFT_BLOCK_S and turned into the trunk's frame, are correlated by ρ, and n such
        # fits hold the information of n / (1 + (n − 1) ρ) (the tilt drifts' bias errors
        # were correlated 0.5–0.65 from sensor to sensor, each counted whole)
        shared = 1.0 / (1.0 + (n - 1) * _common_share(tilts, turns))
        for i, sensor in enumerate(sensors):
            tilt = tilts[sensor]
            if tilt is None:
                continue
            for one in (bias(i), mean_noise(i, p)):
                evidence[one] += shared * tilt[1]
                for other in (bias(i), mean_noise(i, p)):
                    information[one, other] += shared * tilt[0]
    x = np.linalg.solve(information, evidence)
    acc, _, _ = tracks["trunk"].window(min(plan.npose.start, plan.tpose.start),
                                       max(plan.npose.end, plan.tpose.end))
    if not len(acc):
        return None
    up = _up(_unit_rows(acc))
    covariance = np.linalg.inv(information)
    arm = {sensor: (x[bias(k)], covariance[bias(k), bias(k)])
           for k, sensor in enumerate(arms, start=1)}
    trunk = covariance[:3, :3]
    return PoseBiases(float(x[:3] @ up), up, float(np.sqrt(up @ trunk @ up)), arm,
                      (x[:3], trunk))


#: The band a trunk's sway is taken to fill [Hz], flat: slower than 20 s is a posture, not
#: a sway; faster than 2 s the accelerometer's own noise and the sway's accelerations.
SWAY_BAND_HZ = (0.05, 0.5)
#: The sway's spectrum the centre's error covariance is told under, ∝ f^−SWAY_ERROR_SLOPE on
#: ``SWAY_BAND_HZ`` (the weights stay the flat band's): a body's sway is red, its power
#: below 0.1 Hz under ¾ of a cycle in 7.5 s, which the blocks' scatter barely shows, so
#: the flat band under-told it (random sway, 9-axis, 3-s N-pose, side lean's mean
#: normalised squared error 2.87 on seeds 1–10 and 21–60, 3.58 held out on 11–20); pink
#: (1) 1.03 / 1.28 (bench/README.md). A sway that is one or a few sines at 0.1–0.2 Hz is
#: over-told by it (0.1–0.5), until the session tells it again (``sway.retold_lean``).
SWAY_ERROR_SLOPE = 1.0
#: The blocks the trunk's up direction is averaged over before the fit [s], and the noise
#: left in a block's mean, as a fraction of the sway's σ.
SWAY_BLOCK_S = 0.25
SWAY_NOISE = 0.1
#: At most this many blocks (a minute of ``SWAY_BLOCK_S``; a longer span has longer blocks:
#: the fit's work grows as the blocks' count cubed, and the span is as long as the kit's
#: poses were held).
SWAY_MAX_BLOCKS = 240


def _sway_centre(t: np.ndarray, up: np.ndarray, confidence: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The trunk's upright (unit, sensor frame) from its up directions ``up`` (N, 3) at
    times ``t`` [s] through a sway, and that upright's error covariance (3, 3) [rad²,
    sensor frame]. The sway's lean is seen only in its changes; a plain
    mean over a few seconds keeps what its slow partial cycles did not average out (up to
    2–3° at 0.1–0.2 Hz over the poses' 7.5 s). Taken as a zero-mean process filling
    ``SWAY_BAND_HZ`` flat, plus ``SWAY_NOISE``, the upright is the best linear unbiased
    estimate of its mean (generalised least squares over ``SWAY_BLOCK_S`` blocks): weights
    that sum to one and cancel the band's partial cycles as far as the span allows (the
    ends weigh most: they pin the slow part). A still trunk's is its mean to within the
    noise. At most ``SWAY_MAX_BLOCKS`` blocks. The covariance is the model's (the weights'
    ``wᵀ C w``) scaled by the sway's size, which the blocks' scatter about the upright gives
    against what the model expects of it (``tr(P C Pᵀ)``, ``P`` the residual's operator):
    long spans and still trunks make it small. ``confidence`` (e.g. 0.95): the covariance
    at that one-sided bound of the sway's size instead, whose scatter has only
    ``ν = tr(M)² / tr(M²)`` degrees of freedom (``M = P C Pᵀ``): few over a short span, in
    which a slow sway barely moves."""
    length = max(SWAY_BLOCK_S, float(t[-1] - t[0]) / (SWAY_MAX_BLOCKS - 1))
    block = np.minimum(np.floor((t - t[0]) / length).astype(int), SWAY_MAX_BLOCKS - 1)
    count = np.bincount(block)
    kept = count > 0
    times = (np.bincount(block, t) / np.maximum(count, 1))[kept]
    means = np.stack([np.bincount(block, up[:, k]) for k in range(3)], axis=1)[kept]
    means /= count[kept, None]
    lo, hi = SWAY_BAND_HZ
    tau = np.abs(times[:, None] - times[None, :])
    noise = SWAY_NOISE**2 * np.diag(count[kept].max() / count[kept])
    covariance = _band_covariance(tau, lo, hi, 0.0) + noise
    weights = np.linalg.solve(covariance, np.ones(len(times)))
    weights /= weights.sum()
    centre = weights @ means
    residual = means - centre
    spread = np.eye(len(times)) - weights[None, :]  # residual = spread @ means
    told = _band_covariance(tau, lo, hi, SWAY_ERROR_SLOPE) + noise
    residual_covariance = spread @ told @ spread.T
    expected = float(np.trace(residual_covariance))
    scatter = residual.T @ residual / max(expected, 1e-300)  # the sway's (3, 3) [rad²]
    error = scatter * float(weights @ told @ weights)
    if confidence is not None:
        dof = expected**2 / max(float(np.sum(residual_covariance**2)), 1e-300)
        error *= dof / chi2.ppf(1.0 - confidence, dof)
    norm = np.linalg.norm(centre)
    return centre / norm, error / norm**2


#: How sure the live guide must be of the sway's size before it says the trunk is pinned
#: (a one-sided bound; the usual 95 %).
GUIDE_CONFIDENCE = 0.95


def held_side_lean_sd_deg(t: np.ndarray, acc: np.ndarray) -> float | None:
    """How well a pose held so far pins the thorax's side lean through a trunk's sway: one
    σ [deg] of the sway's centre (``_sway_centre``) over the trunk sensor's samples at
    ``t`` [s] (acc [m/s²], sensor frame) along the thorax's lateral axis, taken as the
    default mounting's turned to that centre (the arm's poses that find it are not done
    yet; a sensor turned up to 25° about the thorax's long axis mixes in cos²/sin² of the
    forward lean's variance). At the one-sided ``GUIDE_CONFIDENCE`` bound of the sway's
    size (``_sway_centre``'s ``confidence``): a trunk in a slow stretch of its sway barely
    moves for seconds, and the point estimate said 'pinned' at 2.5–4.5 s (and at 8.5 s on
    an irregular sway) on kits whose whole poses then gave 0.5–1.1°
    (``test_the_guides_steady_is_not_contradicted_by_the_calibration``); a still trunk is
    pinned even so (0.19° at 2.5 s). None under two blocks' span."""
    if len(t) < 2 or t[-1] - t[0] < 2 * SWAY_BLOCK_S:
        return None
    centre, covariance = _sway_centre(t, _unit_rows(acc), confidence=GUIDE_CONFIDENCE)
    lateral = tilt_only_R_sensor_segment(centre, "trunk", "right")[:, 2]  # (any side)
    return float(np.rad2deg(np.sqrt(lateral @ covariance @ lateral)))


def _band_covariance(tau: np.ndarray, lo: float, hi: float, slope: float) -> np.ndarray:
    """The correlation at lags ``tau`` [s] (≥ 0) of a process whose spectrum is ∝ f^−slope
    on ``lo…hi`` [Hz] (slope 0 or 1), 1 at lag 0."""
    w_lo, w_hi = 2 * np.pi * lo * tau, 2 * np.pi * hi * tau
    if slope == 0.0:
        safe = np.where(tau == 0.0, 1.0, tau)
        return np.where(tau == 0.0, 1.0, (np.sin(w_hi) - np.sin(w_lo))
                        / (2 * np.pi * (hi - lo) * safe))
    if slope != 1.0:
        raise ValueError(f"slope must be 0 or 1, got {slope}")
    # ∫ cos(2πfτ) / f df = Ci(2π hi τ) − Ci(2π lo τ); at τ = 0 the band's log width
    ci = sici(np.where(tau == 0.0, 1.0, w_hi))[1] - sici(np.where(tau == 0.0, 1.0, w_lo))[1]
    return np.where(tau == 0.0, 1.0, ci / np.log(hi / lo))


def _sway_range(trunk: SensorTrack, start: float, end: float, axis: np.ndarray) -> float:
    """How far the trunk's up direction (its filter's tilt, trunk sensor frame) moved
    along ``axis`` over ``start…end``: max − min [rad, small angles]."""
    _, _, q = trunk.window(start, end)
    along = quat_to_matrix(q)[:, 2, :] @ axis  # world z in the sensor frame, along axis
    return float(along.max() - along.min()) if len(along) else 0.0


def calibrate(tracks: Mapping[str, SensorTrack], plan: CalibrationPlan, side: Side,
              final_time_s: float, headings: Mapping[str, float] | None = None
              ) -> Calibration:
    """Calibrate from the tracks (each holding at least the data up to ``final_time_s``).
    ``headings``: a first pass's per-sensor headings [rad] that put a 6-axis kit's filters
    in one world (``Calibration.heading``); given, the trunk's sway is taken out as on a
    9-axis kit (a 6-axis kit with a trunk sensor and two poses calibrates twice)."""
    warnings: list[CalibrationWarning] = []
    method = plan.method
    windows = {}
    labels = {"npose": "N-pose", "tpose": "T-pose"}
    for pose in (plan.npose, plan.tpose):
        if pose is None:
            continue
        for sensor, track in tracks.items():
            windows[sensor, pose.name] = track.window(pose.start, pose.end)
        warnings += pose_stillness_warnings(labels[pose.name], {
            sensor: windows[sensor, pose.name][1::-1] for sensor in tracks})
    empty = sorted({pose for (_, pose), (acc, _, _) in windows.items() if len(acc) < 2})
    if method != "default" and empty:
        method = "default"
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            f"the {', '.join(labels[p] for p in empty)} window holds no samples of some "
            f"sensor: the sensors are taken to sit as the kit's guide shows them; redo the "
            f"poses with every sensor on for exact angles"))
    elif method == "default":
        warnings.append(CalibrationWarning(
            "default-mounting", None,
            "no calibration pose: the sensors are taken to sit as the kit's guide shows "
            "them and the arm to hang straight at the start; angles may be off by how far "
            "they do not. Start the next session with the N-pose and T-pose"))

    nine_axis = all(track.nine_axis and not track.magnetometer_dropped
                    for track in tracks.values())
    # A trunk that sways through the poses tilts the whole body with it: an arm sensor's
    # gravity then gives its segment's axes off by the sway's mean over each pose. The
    # trunk sensor sees the sway; its upright is the centre of its up direction over both
    # poses and the time between (the trunk does not move between them; ``_sway_centre``
    # over seconds is nearer upright than over one pose), and the arm takes the thorax's
    # up, not gravity's, carried through both sensors' orientations. Only where all
    # sensors share a heading (9-axis): the carried direction would otherwise turn by the
    # sensors' heading difference; and not when the trunk sensor turned like an arm
    # between the poses (then it is not on the trunk: see the turn warnings).
    sway_corrected = ((nine_axis or headings is not None) and "trunk" in tracks
                      and method != "default")
    # the turn about the vertical of the trunk's filter world into each sensor's
    turns = {s: 0.0 if headings is None else headings["trunk"] - headings[s] for s in tracks}
    if sway_corrected and method == "two-pose":
        sway_corrected = turn_warning("trunk", _up(windows["trunk", "npose"][0]),
                                      _up(windows["trunk", "tpose"][0])) is None
    if sway_corrected:
        span = [p for p in (plan.npose, plan.tpose) if p is not None]
        t_trunk, acc_trunk, _, _ = tracks["trunk"].arrays()
        a = np.searchsorted(t_trunk, min(p.start for p in span), "left")
        b = np.searchsorted(t_trunk, max(p.end for p in span), "right")
        trunk_up, up_covariance = _sway_centre(t_trunk[a:b], _unit_rows(acc_trunk[a:b]))
        # That centre still keeps what the span cannot tell from a tilted mounting (random
        # sway seeds 1–10: 0.88° RMS, the plain mean's 1.02°; 0.46° with the true upright).
        # Its part toward the thorax's X (a forward lean) hurts most: the T-pose turns the
        # arm about X, so the two-direction arm calibration makes that lean a turn about
        # the vertical; a side lean (about X) tilts every segment alike (random seed 9:
        # 2° of it, shoulder rotation 1.5°). The thorax's X is the axis the arm turned about
        # between the poses relative to the trunk sensor (a sway turns both alike), and the
        # upright is square to it. Weighed against the centre (Bayes): the centre's error
        # is within half the trunk's tilt range along X (a sway seen over half a cycle or
        # more), taken as 2σ; the axis's σ is AXIS_SIGMA_RAD's; a still trunk keeps its
        # centre.
        axis = _abduction_axis(tracks, plan, turns) if method == "two-pose" else None
        weight = 0.0
        if axis is not None:
            along = trunk_up @ axis
            sway = 0.25 * _sway_range(tracks["trunk"], min(p.start for p in span),
                                      max(p.end for p in span), axis)
            weight = sway**2 / (sway**2 + AXIS_SIGMA_RAD[nine_axis]**2)
            trunk_up = trunk_up - weight * along * axis
            trunk_up /= np.linalg.norm(trunk_up)

    def pose_up(sensor: str, pose: str) -> np.ndarray:
        if sway_corrected and sensor == "trunk" and not nine_axis:
            return trunk_up  # (a 9-axis trunk takes its axes whole from the arm, below)
        if sway_corrected and sensor in ARM:
            window = plan.npose if pose == "npose" else plan.tpose
            return _thorax_up(tracks[sensor], tracks["trunk"], window.start, window.end,
                              trunk_up, turns[sensor])
        return _up(windows[sensor, pose][0])

    R_sensor_segment: dict[str, np.ndarray] = {}
    for sensor in tracks:
        if method == "default":
            R_sensor_segment[sensor] = default_R_segment_sensor(sensor, side).T
            continue
        up_n = pose_up(sensor, "npose")
        if sensor in ARM and method == "two-pose":
            up_t = pose_up(sensor, "tpose")
            R_sensor_segment[sensor] = two_pose_R_sensor_segment(up_n, up_t, side)
        else:
            R_sensor_segment[sensor] = tilt_only_R_sensor_segment(up_n, sensor, side)
        if method == "two-pose":  # how far gravity turned (not the sway-corrected up)
            warning = turn_warning(sensor, _up(windows[sensor, "npose"][0]),
                                   _up(windows[sensor, "tpose"][0]))
            if warning:
                warnings.append(warning)

    reference = next((s for s in ARM if s in tracks), next(iter(tracks)))
    heading = {sensor: 0.0 for sensor in tracks}

    def npose_segment(sensor: str) -> np.ndarray:
        if method == "default":
            t, _, _, q = tracks[sensor].arrays()
            q = q[: max(1, int(np.searchsorted(t, t[0] + 1.0)))]  # the first second
        else:
            q = windows[sensor, "npose"][2]
        return _mean_rotation(q) @ R_sensor_segment[sensor]

    R_world_thorax = npose_segment(reference) if reference in ARM else np.eye(3)
    for sensor in tracks:
        if not nine_axis and sensor != reference:
            # one world for all: the turn about the vertical that makes this segment point
            # where the reference's points in the N-pose
            heading[sensor] = float(yaw_of(npose_segment(reference)
                                           @ npose_segment(sensor).T))
        if sensor in ("trunk", "clavicle") and reference in ARM and method != "default":
            if nine_axis:
                # the magnetometer shares the heading: take it whole from the arm
                R_ws = _mean_rotation(windows[sensor, "npose"][2])
                R_sensor_segment[sensor] = heading_from_arm(R_ws, R_world_thorax)
    if "trunk" in tracks and reference not in ARM:
        R_world_thorax = npose_segment("trunk")
    if (not nine_axis and headings is None and "trunk" in tracks and reference in ARM
            and method == "two-pose"):
        # The first pass put the filters in one world, the trunk's with its default
        # mounting's turn about its long axis (the N-pose alone cannot tell the two
        # apart). The held poses' sway turns arm and trunk as one: their gyroscopes give
        # the turn between their worlds, weighed against that default (Bayes).
        first = heading["trunk"]
        weight, total = 1.0 / TRUNK_TURN_SIGMA_RAD**2, 0.0
        for pose in (plan.npose, plan.tpose):
            found = _gyro_heading(tracks[reference], tracks["trunk"], pose.start, pose.end)
            if found is not None:
                offset = (found[0] - first + np.pi) % (2 * np.pi) - np.pi
                weight += 1.0 / found[1] ** 2
                total += offset / found[1] ** 2
        # then take the trunk's sway out
        return calibrate(tracks, plan, side, final_time_s,
                         headings={**heading, "trunk": first + total / weight})
    if headings is not None and "trunk" in tracks and reference in ARM:
        # the trunk's world as the gyroscopes put it; its segment as the N-pose does: the
        # sensor's turn about the thorax's long axis (its Y) takes up the difference
        turn = heading["trunk"] - headings["trunk"]
        R_sensor_segment["trunk"] = R_sensor_segment["trunk"] @ Rotation.from_rotvec(
            [0.0, turn, 0.0]).as_matrix()
        heading["trunk"] = headings["trunk"]
    lean_sd_deg, basis = None, None
    if sway_corrected:
        # the thorax's X (forward) and Z (lateral) in the trunk sensor's frame: a side lean
        # (about X) moves the upright along Z, a forward lean (about Z) along X; the axis
        # correction replaced the share ``weight`` of the forward part by the axis's own
        basis = LeanBasis(start=float(t_trunk[a]), end=float(t_trunk[b - 1]),
                          lateral=R_sensor_segment["trunk"][:, 2].copy(),
                          forward=R_sensor_segment["trunk"][:, 0].copy(),
                          up_covariance=up_covariance, axis_weight=float(weight),
                          axis_var=float(AXIS_SIGMA_RAD[nine_axis]**2), nine_axis=nine_axis)
        lean_sd_deg = basis.lean_sd_deg()
        if (warning := trunk_sway_warning(*lean_sd_deg, nine_axis)) is not None:
            warnings.append(warning)
    return Calibration(method=method, final_time_s=final_time_s,
                       R_sensor_segment=R_sensor_segment, heading=heading,
                       R_world_thorax=R_world_thorax, warnings=tuple(warnings),
                       lean_sd_deg=lean_sd_deg, lean_basis=basis)


