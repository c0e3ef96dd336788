"""The recursion of the quaternion complementary filter (``qcf``), one sample at a time.

This is the only per-sample loop of the estimator. It is plain Python on scalars so that
numba can compile it (``kernel``); ``kernel_python`` is the same function uncompiled, the
fallback when numba is not installed, and gives the same numbers to 1e-9.

The estimate is split in three, as in VQF (Laidig & Seel 2023):
``q = Rz(δ) · q_acc · q_gyr`` — ``q_gyr`` integrates the bias-corrected gyroscope from the
sensor to a drifting inertial frame I; ``q_acc`` tilts I onto the earth frame E so that the
low-passed specific force, filtered *in I*, points up; ``δ`` turns E about the vertical so
the magnetometer's horizontal part points north (9-axis only). Filtering the specific force
in the inertial frame with a second-order low-pass removes the body's own acceleration far
better than a first-order correction: its residue is about ``x ω0²`` for a displacement
``x`` (``ω0 = √2 / tau_acc``) instead of ``v ω0`` for a velocity ``v``.

State layout (float64): ``[0:4]`` q_gyr · ``[4:8]`` q_acc · ``[8]`` δ [rad] · ``[9:12]``
gyroscope bias [rad/s] · ``[12]`` last t [s] · ``[13]`` initialised · ``[14]`` time still so
far [s] · ``[15:18]`` low-passed gyroscope · ``[18:21]`` low-passed accelerometer (sensor) ·
``[21:24]`` filtered specific force in I · ``[24:27]`` its rate · ``[27]`` reference field
norm [µT] · ``[28]`` reference dip [rad] · ``[29]`` time disturbed so far [s] · ``[30:33]``
sum of the gyroscope over the current rest · ``[33]`` samples in it · ``[34:37]`` sum of
the samples still waiting for the guard time · ``[37]`` their count · ``[38]`` their
time · ``[39:42]`` the previous gyroscope sample · ``[42]`` the first sample's time
· ``[43]`` whether a rest has taught the bias · ``[44:63]`` the field-turning bias
estimator (before a rest): window sums V, Y [44:50], the heading's ∫φ u dt [50:53] (u the
vertical in the sensor frame), window time [53], the bias's covariance P [54:60]
(00, 11, 22, 01, 02, 12; rad²/s²), the heading's ∫φ u·b dt [60] and weighted drift [61],
the last heading error [62] · ``[63:66]`` the previous field sample · ``[66]`` a
window is open · ``[67:70]`` the low-passed accelerometer when the current rest began
· ``[70:73]`` the candidate reference field in E [µT] · ``[73]`` how far the sensor
turned while the field stayed with the candidate [rad] · ``[74]`` the same for the
reference (its confirmation) [rad]
· ``[75]`` when the heading's warm-up (running mean of the readings) began [s] · ``[76]``
the time the candidate has held [s] · ``[77]`` the rest time [s] the bias was learnt
from (a rest's second counts as much as any before, until ``tau_bias_rest`` of them) ·
``[78:81]`` the accelerometer low-passed over ``tau_rest_acc`` (the rest detector's) ·
``[81]`` the time of the last rest sample [s] · ``[82]`` how stillness last taught the
bias (0 never, 1 a still start's provisional bias, 2 a rest) · ``[83]`` when [s] · ``[84]``
the seconds of stillness it was learnt from then (the bias before any is the filter's
starting one: zero, or a remembered bias, ``QuaternionComplementaryFilter.gyr_bias_prior``)
· ``[85]`` the last heading step [rad] · ``[86]`` the window's Σ(Δφ)² · ``[87]``, ``[88]``
the scatter the field-turning and heading equations show [µT², rad²] · ``[89]`` the
windows so far · ``[90:99]`` R (sensor → I, rows) low-passed as the specific force is ·
``[99:108]`` its rate · ``[108:111]`` R b_subtracted low-passed alike [rad/s] ·
``[111:114]`` its rate · the tilt's bias window: ``[114:123]`` ∫ LP(R) dt [s],
``[123:126]`` ∫ LP(R b_subtracted) dt minus the tilt corrections (in I) [rad],
``[126]`` its time [s] · ``[127]`` the scatter its equations show [rad²] · ``[128]`` its
equations so far · ``[129]`` the window's turn [rad] · ``[130:133]`` the bias the filter
started from (zero or the prior) [rad/s] · a still start's accelerometer: ``[133:136]``
the sum over the block waiting for the guard time, ``[136:139]`` its first block's mean and
``[139]`` that block's mid time [s], ``[140:143]`` its latest block's mean, ``[143]`` its
mid time [s], ``[144:147]`` and ``[147:150]`` the gyroscope's sums over the first and the
latest block [rad/s], ``[150]`` the accelerometer's Σ|a|² over the waiting block
[m²/s⁴], ``[151]``, ``[152]`` the variance of the first and the latest block's mean [m²/s⁴]
· ``[153:156]`` the previous gyroscope sample at its own time (the kit's gyroscope delay
taken out, see below) [rad/s] · ``[156]`` the current stillness's Σ (gyroscope deviation
from its low-pass)² dt [rad²/s] · ``[157:160]`` the turn away from the low-passed rate's
path (its high-pass over ``tau_lp``) [rad] · ``[160]`` 1.0 when ``[161:167]`` hold the
starting bias's covariance (p00, p11, p22, p01, p02, p12 [rad²/s²]: a prior known better
than ``bias_sigma`` along some axis, ``QuaternionComplementaryFilter.gyr_bias_prior_cov``;
the bias starts from it, and a still start taken back returns to it), 0.0: ``bias_sigma``²
· ``[167]`` the heading's own σ [rad]: grown by the bias's σ about the vertical, shrunk by
each clean field reading as a Kalman step would (9-axis only).

A kit whose gyroscope lags its accelerometer (``params[P_GYRO_DELAY]`` = d [s]: sample i's
rates are those of ``t[i] − d``; 0 for most kits) is integrated over the accelerometer's
own interval by the linear extrapolation ``∫ ≈ dt (ω[i−1] + ω[i]) / 2 + d (ω[i] − ω[i−1])``
(exact for a rate linear in time; d = dt / 2 gives VQF's ``ω[i] dt``); its difference
terms telescope, so the gyroscope's noise is not amplified over a session. The field's
turning (``ω × m`` at one instant) takes the rate extrapolated to the field's time,
``ω[i] + d (ω[i] − ω[i−1]) / dt``. The rest detector (0.5-s low-pass, per-sample
deviations) and the bias means (of a constant bias, over ≥ 0.2 s) do not see a delay of a
few milliseconds and take the samples as they are. d = 0 gives today's numbers exactly.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import compiler
from ..scalar_linalg import sym3_adjugate
from ..scalar_rotations import quat_to_rows

STATE_SIZE = 168

# Indices into the parameter vector, see QcfParams.as_array.
(P_TAU_ACC, P_TAU_MAG, P_TAU_LP, P_REST_GYR, P_REST_ACC, P_REST_TIME,
 P_KI_BIAS, P_KI_BIAS_MAG, P_BIAS_MAX, P_MAG_NORM_TOL, P_MAG_DIP_TOL, P_TAU_MAG_REF,
 P_MAG_REACCEPT, P_MAX_DT, P_REST_MIN_SAMPLES, P_REST_GUARD, P_TAU_ACC_REST,
 P_REST_RATE, P_TAU_BIAS_REST, P_REST_RATE_KNOWN, P_ZUPT_DELAY, P_MAG_WINDOW,
 P_BIAS_WALK, P_MAG_NOISE, P_REST_TILT, P_REST_TIME_FIRST, P_REST_GUARD_FIRST,
 P_MAG_CONFIRM_TURN, P_REST_MIN_SAMPLES_FIRST, P_MAG_HOLD_WEIGHT, P_MAG_RESTART,
 P_TAU_REST_ACC, P_MAG_BIAS_HALF_TIME, P_BIAS_SIGMA, P_MAG_SCATTER_WINDOWS,
 P_TILT_NOISE, P_TILT_WINDOW, P_GYRO_SCALE, P_REST_VIBRATION) = range(39)
PARAM_SIZE = 39
#: The kernel's parameter vector is ``QcfParams.as_array()`` followed by the gyroscope's
#: delay behind the accelerometer [s] (a property of the kit, not a tuning).
P_GYRO_DELAY = PARAM_SIZE
KERNEL_PARAM_SIZE = PARAM_SIZE + 1


def _field_turn_update(bx, by, bz, p00, p11, p22, p01, p02, p12, vx, vy, vz, yx, yy, yz,
                       white, scatter, k):
    """One Kalman step of the bias b [rad/s] (covariance P, symmetric, [rad²/s²]) from a
    window's field-turning equation ``b × V = Y`` (V [µT·s], Y [µT]): ``Y = H b`` with
    ``H = −[V]×``. The noise variance of each axis of Y [µT²] is the larger of ``white``
    and ``scatter``, the running mean (gain ``k``) of what the windows' innovations show,
    (|ν|² − tr(H P Hᵀ)) / 3, this one's included. Returns b, P and that mean."""
    # A = [V]× (rows), M = P Aᵀ, S = A P Aᵀ + r I
    a0x, a0y, a0z = 0.0, -vz, vy
    a1x, a1y, a1z = vz, 0.0, -vx
    a2x, a2y, a2z = -vy, vx, 0.0
    # M[i][j] = P_i · A_j
    m00 = p00 * a0x + p01 * a0y + p02 * a0z
    m01 = p00 * a1x + p01 * a1y + p02 * a1z
    m02 = p00 * a2x + p01 * a2y + p02 * a2z
    m10 = p01 * a0x + p11 * a0y + p12 * a0z
    m11 = p01 * a1x + p11 * a1y + p12 * a1z
    m12 = p01 * a2x + p11 * a2y + p12 * a2z
    m20 = p02 * a0x + p12 * a0y + p22 * a0z
    m21 = p02 * a1x + p12 * a1y + p22 * a1z
    m22 = p02 * a2x + p12 * a2y + p22 * a2z
    # innovation ν = Y − b × V = Y + V × b; the noise it shows: E|ν|² = tr(A P Aᵀ) + 3 r
    nx = yx + vy * bz - vz * by
    ny = yy + vz * bx - vx * bz
    nz = yz + vx * by - vy * bx
    s00 = a0x * m00 + a0y * m10 + a0z * m20
    s11 = a1x * m01 + a1y * m11 + a1z * m21
    s22 = a2x * m02 + a2y * m12 + a2z * m22
    scatter += k * ((nx * nx + ny * ny + nz * nz - (s00 + s11 + s22)) / 3.0 - scatter)
    r = max(white, scatter)
    # S[i][j] = A_i · M[:, j] (+ r on the diagonal)
    s00 += r
    s11 += r
    s22 += r
    s01 = a0x * m01 + a0y * m11 + a0z * m21
    s02 = a0x * m02 + a0y * m12 + a0z * m22
    s12 = a1x * m02 + a1y * m12 + a1z * m22
    # S⁻¹ (symmetric, positive definite: r > 0)
    c00, c01, c02, c11, c12, c22, det = sym3_adjugate(s00, s11, s22, s01, s02, s12)
    if not det > 0.0:
        return bx, by, bz, p00, p11, p22, p01, p02, p12, scatter
    f = 1.0 / det
    u00, u01, u02, u11, u12, u22 = c00 * f, c01 * f, c02 * f, c11 * f, c12 * f, c22 * f
    gx = u00 * nx + u01 * ny + u02 * nz
    gy = u01 * nx + u11 * ny + u12 * nz
    gz = u02 * nx + u12 * ny + u22 * nz
    # K = P Hᵀ S⁻¹ = −M S⁻¹: b += K ν
    bx -= m00 * gx + m01 * gy + m02 * gz
    by -= m10 * gx + m11 * gy + m12 * gz
    bz -= m20 * gx + m21 * gy + m22 * gz
    # P −= M S⁻¹ Mᵀ; W = M S⁻¹ (rows)
    w00 = m00 * u00 + m01 * u01 + m02 * u02
    w01 = m00 * u01 + m01 * u11 + m02 * u12
    w02 = m00 * u02 + m01 * u12 + m02 * u22
    w10 = m10 * u00 + m11 * u01 + m12 * u02
    w11 = m10 * u01 + m11 * u11 + m12 * u12
    w12 = m10 * u02 + m11 * u12 + m12 * u22
    w20 = m20 * u00 + m21 * u01 + m22 * u02
    w21 = m20 * u01 + m21 * u11 + m22 * u12
    w22 = m20 * u02 + m21 * u12 + m22 * u22
    p00 -= w00 * m00 + w01 * m01 + w02 * m02
    p11 -= w10 * m10 + w11 * m11 + w12 * m12
    p22 -= w20 * m20 + w21 * m21 + w22 * m22
    p01 -= w00 * m10 + w01 * m11 + w02 * m12
    p02 -= w00 * m20 + w01 * m21 + w02 * m22
    p12 -= w10 * m20 + w11 * m21 + w12 * m22
    return bx, by, bz, p00, p11, p22, p01, p02, p12, scatter


def _heading_update(bx, by, bz, p00, p11, p22, p01, p02, p12, hx, hy, hz, y, white, scatter, k):
    """One Kalman step of the bias b [rad/s] (covariance P) from a scalar equation
    ``h · b = y``, its noise variance the larger of ``white`` and ``scatter``, the running
    mean (gain ``k``) of what the innovations show, ν² − h P h, this one's included.
    Returns b, P and that mean."""
    # g = P h, S = h P h + r, K = g / S
    gx = p00 * hx + p01 * hy + p02 * hz
    gy = p01 * hx + p11 * hy + p12 * hz
    gz = p02 * hx + p12 * hy + p22 * hz
    hph = hx * gx + hy * gy + hz * gz
    nu = y - (hx * bx + hy * by + hz * bz)
    scatter += k * (nu * nu - hph - scatter)  # E ν² = h P h + r
    sv = hph + max(white, scatter)
    if not sv > 0.0:
        return bx, by, bz, p00, p11, p22, p01, p02, p12, scatter
    e = nu / sv
    bx += gx * e
    by += gy * e
    bz += gz * e
    p00 -= gx * gx / sv
    p11 -= gy * gy / sv
    p22 -= gz * gz / sv
    p01 -= gx * gy / sv
    p02 -= gx * gz / sv
    p12 -= gy * gz / sv
    return bx, by, bz, p00, p11, p22, p01, p02, p12, scatter


def _bias_distance(rx, ry, rz, p00, p11, p22, p01, p02, p12, noise):
    """The squared Mahalanobis norm ``rᵀ (P + noise I)⁻¹ r`` of a rate ``r`` [rad/s]
    against the bias's covariance ``P`` [rad²/s²] plus ``noise`` on each axis."""
    a00, a11, a22 = p00 + noise, p11 + noise, p22 + noise
    c00 = a11 * a22 - p12 * p12
    c01 = p02 * p12 - p01 * a22
    c02 = p01 * p12 - p02 * a11
    det = a00 * c00 + p01 * c01 + p02 * c02
    if not det > 0.0:
        return 0.0
    c11 = a00 * a22 - p02 * p02
    c12 = p01 * p02 - a00 * p12
    c22 = a00 * a11 - p01 * p01
    return (rx * (c00 * rx + c01 * ry + c02 * rz) + ry * (c01 * rx + c11 * ry + c12 * rz)
            + rz * (c02 * rx + c12 * ry + c22 * rz)) / det


def _compile_helper():
    jit = compiler(inline="always")
    if jit is None:
        return _field_turn_update, _heading_update, _bias_distance
    return jit(_field_turn_update), jit(_heading_update), jit(_bias_distance)


field_turn_update, heading_update, bias_distance = _compile_helper()


def kernel_python(t, acc, gyr, mag, has_mag, params, state, out_q, out_bias, out_rest,
                  out_disturbed):
    """Run the filter over samples ``0..N-1``, updating ``state`` in place and writing the
    outputs. ``has_mag``: 1 when ``mag`` holds magnetometer rows, 0 otherwise.

    Returns −1, or — touching nothing — the index of the first sample whose time is not
    finite or goes backwards (from the previous sample, or for sample 0 from the last
    one of the previous chunk)."""
    previous = state[12] if state[13] != 0.0 else -math.inf
    for i in range(t.shape[0]):
        if not t[i] >= previous:  # also false for NaN
            return i
        previous = t[i]
    tau_acc = params[P_TAU_ACC]
    tau_mag = params[P_TAU_MAG]
    tau_lp = params[P_TAU_LP]
    rest_gyr = params[P_REST_GYR]
    rest_rate = params[P_REST_RATE]
    rest_rate_known = params[P_REST_RATE_KNOWN]
    tau_bias_rest = params[P_TAU_BIAS_REST]
    zupt_delay = params[P_ZUPT_DELAY]
    mag_window = params[P_MAG_WINDOW]
    bias_walk = params[P_BIAS_WALK]
    mag_noise = params[P_MAG_NOISE]
    bias_var = params[P_BIAS_SIGMA] * params[P_BIAS_SIGMA]
    mag_scatter_windows = params[P_MAG_SCATTER_WINDOWS]
    rest_acc = params[P_REST_ACC]
    rest_time_needed = params[P_REST_TIME]
    ki_bias = params[P_KI_BIAS]
    ki_bias_mag = params[P_KI_BIAS_MAG]
    bias_max = params[P_BIAS_MAX]
    mag_norm_tol = params[P_MAG_NORM_TOL]
    mag_dip_tol = params[P_MAG_DIP_TOL]
    tau_mag_ref = params[P_TAU_MAG_REF]
    mag_reaccept = params[P_MAG_REACCEPT]
    max_dt = params[P_MAX_DT]
    rest_min_samples = params[P_REST_MIN_SAMPLES]
    rest_guard = params[P_REST_GUARD]
    tau_acc_rest = params[P_TAU_ACC_REST]
    cos_rest_tilt = math.cos(params[P_REST_TILT])
    rest_tilt_angle = params[P_REST_TILT]
    rest_time_first = params[P_REST_TIME_FIRST]
    rest_guard_first = params[P_REST_GUARD_FIRST]
    mag_confirm_turn = params[P_MAG_CONFIRM_TURN]
    dt0 = 1e-3  # the weight of the first sample of a candidate [s]
    cos_candidate = math.cos(2.0 * mag_dip_tol)
    rest_min_samples_first = params[P_REST_MIN_SAMPLES_FIRST]
    mag_hold_weight = params[P_MAG_HOLD_WEIGHT]
    mag_restart = params[P_MAG_HOLD_WEIGHT + 1]
    tau_rest_acc = params[P_TAU_REST_ACC]
    mag_bias_half_time = params[P_MAG_BIAS_HALF_TIME]
    tilt_white = params[P_TILT_NOISE] * params[P_TILT_NOISE]
    tilt_window = params[P_TILT_WINDOW]
    gyro_scale = params[P_GYRO_SCALE]
    gyro_delay = params[P_GYRO_DELAY]
    rest_vibration = params[P_REST_VIBRATION]
    # the bias's variance after a rest taught it: the rest's mean over tau_bias_rest
    # of a random walk
    rest_var = bias_walk * bias_walk * tau_bias_rest

    gw, gx, gy, gz = state[0], state[1], state[2], state[3]
    cw, cx, cy, cz = state[4], state[5], state[6], state[7]
    delta = state[8]
    bx, by, bz = state[9], state[10], state[11]
    t_last = state[12]
    initialised = state[13]
    still_time = state[14]
    glx, gly, glz = state[15], state[16], state[17]
    alx, aly, alz = state[18], state[19], state[20]
    fx, fy, fz = state[21], state[22], state[23]
    vx, vy, vz = state[24], state[25], state[26]
    ref_norm, ref_dip = state[27], state[28]
    disturbed_time = state[29]
    sig_h = state[167]
    sx, sy, sz, count = state[30], state[31], state[32], state[33]
    px, py, pz, pending, pending_time = state[34], state[35], state[36], state[37], state[38]
    lwx, lwy, lwz = state[39], state[40], state[41]
    lcx, lcy, lcz = state[153], state[154], state[155]
    t_start = state[42]
    bias_known = state[43]
    mVx, mVy, mVz, mYx, mYy, mYz = state[44], state[45], state[46], state[47], state[48], state[49]
    hx, hy, hz, mw_time = state[50], state[51], state[52], state[53]
    p00, p11, p22, p01, p02, p12 = state[54], state[55], state[56], state[57], state[58], state[59]
    hb, yh, last_error = state[60], state[61], state[62]
    learnt_how, learnt_at, learnt_still = state[82], state[83], state[84]
    b0x, b0y, b0z = state[130], state[131], state[132]
    qax, qay, qaz = state[133], state[134], state[135]
    a0x, a0y, a0z, a0t = state[136], state[137], state[138], state[139]
    a1x, a1y, a1z, a1t = state[140], state[141], state[142], state[143]
    w0x, w0y, w0z, w1x, w1y, w1z = (state[144], state[145], state[146], state[147], state[148],
                                    state[149])
    qa2, va0, va1 = state[150], state[151], state[152]
    last_step, s2 = state[85], state[86]
    scatter_f, scatter_h, n_win = state[87], state[88], state[89]
    lmx, lmy, lmz, m_started = state[63], state[64], state[65], state[66]
    srx, sry, srz = state[67], state[68], state[69]
    cex, cey, cez, cand_turn, ref_turn = state[70], state[71], state[72], state[73], state[74]
    t_mag_start, cand_time = state[75], state[76]
    evidence = state[77]
    afx, afy, afz = state[78], state[79], state[80]
    last_rest = state[81]
    l00, l01, l02, l10, l11, l12, l20, l21, l22 = (state[90], state[91], state[92], state[93],
                                                   state[94], state[95], state[96], state[97],
                                                   state[98])
    d00, d01, d02, d10, d11, d12, d20, d21, d22 = (state[99], state[100], state[101], state[102],
                                                   state[103], state[104], state[105],
                                                   state[106], state[107])
    lbx, lby, lbz, dbx, dby, dbz = (state[108], state[109], state[110], state[111], state[112],
                                    state[113])
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = (state[114], state[115], state[116],
                                                   state[117], state[118], state[119],
                                                   state[120], state[121], state[122])
    zx, zy, zz, tw_time, scatter_t, n_tw = (state[123], state[124], state[125], state[126],
                                            state[127], state[128])
    tw_turn = state[129]
    still_dev2 = state[156]
    hpx, hpy, hpz = state[157], state[158], state[159]

    for i in range(t.shape[0]):
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        wx, wy, wz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        cwx, cwy, cwz = wx, wy, wz  # the rate at the sample's own time (gyro_delay)
        a_norm = math.sqrt(ax * ax + ay * ay + az * az)
        at_rest = False
        disturbed = False

        if initialised == 0.0:
            gw, gx, gy, gz = 1.0, 0.0, 0.0, 0.0
            # q_acc: the shortest rotation taking the measured up (sensor = I now) to +z.
            if a_norm > 0.0:
                ux, uy, uz = ax / a_norm, ay / a_norm, az / a_norm
            else:
                ux, uy, uz = 0.0, 0.0, 1.0
            h = math.sqrt(max(0.5 * (1.0 + uz), 0.0))
            if h > 1e-9:
                cw, cx, cy, cz = h, uy / (2.0 * h), -ux / (2.0 * h), 0.0
            else:
                cw, cx, cy, cz = 0.0, 1.0, 0.0, 0.0
            fx, fy, fz = ax, ay, az
            vx, vy, vz = 0.0, 0.0, 0.0
            glx, gly, glz = wx, wy, wz
            alx, aly, alz = ax, ay, az
            afx, afy, afz = ax, ay, az
            t_last = t[i]
            t_start = t[i]
            initialised = 1.0
            p00, p11, p22, p01, p02, p12 = bias_var, bias_var, bias_var, 0.0, 0.0, 0.0
            if state[160] != 0.0:  # the starting bias's own covariance
                p00, p11, p22 = state[161], state[162], state[163]
                p01, p02, p12 = state[164], state[165], state[166]
            b0x, b0y, b0z = bx, by, bz
            # the tilt's bias equation: R (sensor → I) and R b low-passed as the force is,
            # from the same start (the identity, still before)
            l00, l01, l02, l10, l11, l12 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0
            l20, l21, l22 = 0.0, 0.0, 1.0
            d00, d01, d02, d10, d11, d12 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            d20, d21, d22 = 0.0, 0.0, 0.0
            lbx, lby, lbz, dbx, dby, dbz = bx, by, bz, 0.0, 0.0, 0.0
            if has_mag == 1:
                mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
                # field in E = q_acc m (q_gyr is the identity)
                (r00, r01, r02, r10, r11,
                 r12, r20, r21, r22) = quat_to_rows(cw, cx, cy, cz)
                mex = r00 * mx + r01 * my + r02 * mz
                mey = r10 * mx + r11 * my + r12 * mz
                mez = r20 * mx + r21 * my + r22 * mz
                delta = math.atan2(mex, mey)
                ref_norm = math.sqrt(mx * mx + my * my + mz * mz)
                ref_dip = math.atan2(-mez, math.sqrt(mex * mex + mey * mey))
                cex, cey, cez, cand_turn, ref_turn, cand_time = mex, mey, mez, 0.0, 0.0, dt0
                t_mag_start = t[i]
        else:
            dt = t[i] - t_last
            t_last = t[i]
            if dt < 0.0:
                dt = 0.0
            if dt > max_dt:
                dt = max_dt
            if gyro_delay > 0.0 and dt > 0.0:
                k_d = gyro_delay / dt
                cwx = wx + k_d * (wx - lwx)
                cwy = wy + k_d * (wy - lwy)
                cwz = wz + k_d * (wz - lwz)

            # Rest: gyroscope and accelerometer steady for rest_time seconds.
            k_lp = dt / (tau_lp + dt)
            glx += k_lp * (wx - glx)
            gly += k_lp * (wy - gly)
            glz += k_lp * (wz - glz)
            alx += k_lp * (ax - alx)
            aly += k_lp * (ay - aly)
            alz += k_lp * (az - alz)
            # the deviation of each sample from the low-pass reacts at once to a movement's
            # onset (a smoothed measure would let its first samples into the bias)
            dev_g = math.sqrt((wx - glx) ** 2 + (wy - gly) ** 2 + (wz - glz) ** 2)
            # the turn away from the low-passed rate's path, high-passed over tau_lp
            k_hp = 1.0 - k_lp
            hpx = k_hp * (hpx + (wx - glx) * dt)
            hpy = k_hp * (hpy + (wy - gly) * dt)
            hpz = k_hp * (hpz + (wz - glz) * dt)
            rate = math.sqrt((glx - bx) ** 2 + (gly - by) ** 2 + (glz - bz) ** 2)
            k_f = dt / (tau_rest_acc + dt)
            afx += k_f * (ax - afx)
            afy += k_f * (ay - afy)
            afz += k_f * (az - afz)
            dev_a = math.sqrt((afx - alx) ** 2 + (afy - aly) ** 2 + (afz - alz) ** 2)
            rate_limit = rest_rate if bias_known == 0.0 else rest_rate_known
            from_start = t[i] - still_time <= t_start + 2.0 * dt
            # A sensor on foam or skin vibrates while it lies still (0.03-0.08 rad/s from
            # sample to sample on RING's foam) about its fixed orientation: its mean rate
            # is still its bias. So a stillness from the first sample, until it is a rest
            # (only its provisional bias comes from it), takes a sample whose deviation is
            # within rest_vibration times the stillness's own RMS deviation so far (over
            # its first rest_guard_first, this sample's included: the level is still being
            # learnt), as long as the sensor's turn away from the low-passed rate's path
            # stays within rest_tilt: a vibration turns it to and fro by little, a movement
            # (a limb's, a trunk's sway) away. (The low-pass starts at the first sample:
            # a vibration caught near its peak rate there is not taken.)
            gyr_limit = rest_gyr
            if (bias_known == 0.0 and from_start and still_time + dt < rest_time_needed
                    and still_time + dt > 0.0
                    and math.sqrt(hpx * hpx + hpy * hpy + hpz * hpz) <= rest_tilt_angle):
                if still_time < rest_guard_first:
                    level2 = (still_dev2 + dev_g * dev_g * dt) / (still_time + dt)
                else:
                    level2 = still_dev2 / still_time
                gyr_limit = max(rest_gyr, rest_vibration * math.sqrt(level2))
            still = dev_g < gyr_limit and rate < rate_limit and dev_a < rest_acc
            if still and bias_known == 0.0 and learnt_how == 0.0:
                # The loose rest_rate is rest_rate / bias_sigma (5) σ of an unknown bias; a
                # bias known better (a prior with its covariance: the held poses', or what
                # the corrections in motion taught; not a still start's own provisional
                # one, which its stillness goes on refining) lets a low-passed rate through
                # only within as many of its own σ, plus the low-pass's noise (from the
                # samples' deviation): a slow turn is no rest (a swaying arm hanging in
                # the N-pose, 16 mrad/s, against a prior known to 0.4 mrad/s).
                level2 = dev_g * dev_g  # (equal stamps: no time yet)
                if still_time + dt > 0.0:
                    level2 = (still_dev2 + dev_g * dev_g * dt) / (still_time + dt)
                noise = level2 / 3.0 * k_lp / (2.0 - k_lp)
                still = bias_distance(glx - bx, gly - by, glz - bz, p00, p11, p22, p01,
                                      p02, p12, noise) < rest_rate * rest_rate / bias_var
            if still and bias_known == 0.0 and (
                    not from_start or still_time + dt >= rest_time_needed):
                # Until a rest has taught the bias, the gyroscope cannot tell a slow turn
                # (a trunk's sway) from its bias: through the stillness the low-passed
                # specific force must also keep the direction it had when it began (a
                # stillness from the first sample: when it became a rest, the low-pass
                # having settled by then).
                if still_time == 0.0 or (from_start and still_time < rest_time_needed):
                    srx, sry, srz = alx, aly, alz
                else:
                    dot = alx * srx + aly * sry + alz * srz
                    norms = math.sqrt((alx * alx + aly * aly + alz * alz)
                                      * (srx * srx + sry * sry + srz * srz))
                    still = dot >= cos_rest_tilt * norms
            if still:
                still_time += dt
                still_dev2 += dev_g * dev_g * dt
            else:
                still_time = 0.0
                still_dev2 = 0.0
                px, py, pz, pending, pending_time = 0.0, 0.0, 0.0, 0.0, 0.0
                qax, qay, qaz, qa2 = 0.0, 0.0, 0.0, 0.0
            # A kit that starts still (on a table, held for a second) gives a provisional
            # bias before its stillness is a rest: half a second gives it to a few mrad/s,
            # where integrating an unknown one drifts by degrees a minute. Its samples
            # count once the stillness has gone on rest_guard_first after them.
            initial = still and bias_known == 0.0 and t[i] - still_time <= t_start + 2.0 * dt
            if initial and still_time < rest_time_needed:
                px += wx
                py += wy
                pz += wz
                qax += ax
                qay += ay
                qaz += az
                qa2 += ax * ax + ay * ay + az * az
                pending += 1.0
                pending_time += dt
                if pending_time >= rest_guard_first:
                    mid = t[i] - 0.5 * pending_time
                    mean_x, mean_y, mean_z = qax / pending, qay / pending, qaz / pending
                    # the variance of the block's mean (all axes), from its own scatter
                    spread = max(qa2 / pending - mean_x * mean_x - mean_y * mean_y
                                 - mean_z * mean_z, 0.0) / pending
                    if count == 0.0:
                        a0x, a0y, a0z, a0t, va0 = mean_x, mean_y, mean_z, mid, spread
                        w0x, w0y, w0z = px, py, pz
                    a1x, a1y, a1z, a1t, va1 = mean_x, mean_y, mean_z, mid, spread
                    w1x, w1y, w1z = px, py, pz
                    sx += px
                    sy += py
                    sz += pz
                    count += pending
                    evidence += pending_time
                    px, py, pz, pending, pending_time = 0.0, 0.0, 0.0, 0.0, 0.0
                    qax, qay, qaz, qa2 = 0.0, 0.0, 0.0, 0.0
                if still_time >= rest_time_first and count >= rest_min_samples_first:
                    # Still, or a slow turn (a sway from the first sample) the loose
                    # rest_rate lets through? Had the sensor turned by what the gyroscope
                    # read between the first and the latest block's middles (Ω), gravity
                    # would have turned with it: a turn if the accelerometer is nearer to
                    # that, and moved beyond three times its noise (the blocks' scatter).
                    n0 = math.sqrt(a0x * a0x + a0y * a0y + a0z * a0z)
                    n1 = math.sqrt(a1x * a1x + a1y * a1y + a1z * a1z)
                    turned = False
                    if n0 > 0.0 and n1 > 0.0 and a1t > a0t:
                        step = evidence / count  # the blocks' mean sample interval [s]
                        ox = (sx - 0.5 * (w0x + w1x)) * step
                        oy = (sy - 0.5 * (w0y + w1y)) * step
                        oz = (sz - 0.5 * (w0z + w1z)) * step
                        g0x, g0y, g0z = a0x / n0, a0y / n0, a0z / n0
                        ex, ey, ez = a1x / n1 - g0x, a1y / n1 - g0y, a1z / n1 - g0z
                        # g0 − Ω × g0: a vector fixed in the world, seen from a sensor
                        # that turned by Ω
                        tx = ex + (oy * g0z - oz * g0y)
                        ty = ey + (oz * g0x - ox * g0z)
                        tz = ez + (ox * g0y - oy * g0x)
                        moved = ex * ex + ey * ey + ez * ez
                        turned = (tx * tx + ty * ty + tz * tz < moved
                                  and moved > 9.0 * (va0 / (n0 * n0) + va1 / (n1 * n1)))
                    if not turned:
                        bx, by, bz = sx / count, sy / count, sz / count
                        learnt_how, learnt_at, learnt_still = 1.0, t[i], evidence
                        p00, p11, p22, p01, p02, p12 = (rest_var, rest_var, rest_var,
                                                        0.0, 0.0, 0.0)
                    elif learnt_how == 1.0:  # a later block shows the turn: take it back
                        bx, by, bz = b0x, b0y, b0z
                        p00, p11, p22, p01, p02, p12 = (bias_var, bias_var, bias_var,
                                                        0.0, 0.0, 0.0)
                        if state[160] != 0.0:  # the starting bias's own covariance
                            p00, p11, p22 = state[161], state[162], state[163]
                            p01, p02, p12 = state[164], state[165], state[166]
                        learnt_how, learnt_at, learnt_still = 0.0, 0.0, 0.0
            elif still_time >= rest_time_needed:
                at_rest = True
                last_rest = t[i]
                if still_time - dt < rest_time_needed and not initial:
                    sx, sy, sz, count = 0.0, 0.0, 0.0, 0.0  # a new rest: a new mean
                    if bias_known == 0.0:
                        evidence = 0.0
                # Samples wait rest_guard seconds before they count, so that the slow
                # start of the next movement never leaks into the bias.
                px += wx
                py += wy
                pz += wz
                pending += 1.0
                pending_time += dt
                if pending_time >= rest_guard:
                    if bias_known == 0.0:
                        # the first rest: the bias is the mean of everything so far
                        sx += px
                        sy += py
                        sz += pz
                        count += pending
                        evidence += pending_time
                        if count >= rest_min_samples:
                            bx, by, bz = sx / count, sy / count, sz / count
                            bias_known = 1.0
                            p00, p11, p22 = rest_var, rest_var, rest_var
                            p01, p02, p12 = 0.0, 0.0, 0.0
                            learnt_how, learnt_at, learnt_still = 2.0, t[i], evidence
                    else:
                        # later: follow a drifting bias, each block weighted by its length
                        k_b = pending_time / (min(evidence, tau_bias_rest) + pending_time)
                        evidence += pending_time
                        bx += k_b * (px / pending - bx)
                        by += k_b * (py / pending - by)
                        bz += k_b * (pz / pending - bz)
                        learnt_how, learnt_at, learnt_still = 2.0, t[i], evidence
                        p00, p11, p22, p01, p02, p12 = rest_var, rest_var, rest_var, 0.0, 0.0, 0.0
                    px, py, pz, pending, pending_time = 0.0, 0.0, 0.0, 0.0, 0.0

            # Strapdown: q_gyr ← q_gyr ⊗ exp(½ (ω̄ − b) dt), ω̄ the mean of the rates at the
            # interval's two ends (trapezoidal: second order, no lag of half a sample). At
            # rest the rate is the low-pass's residue (a zero-velocity update): integrating
            # bias and noise there would only add drift, of heading above all.
            # (Only once the rest has outlasted the guard: a slow sway can look still for
            # a second, and freezing it would be worse than the drift.)
            if at_rest and still_time >= rest_time_needed + zupt_delay:
                sbx, sby, sbz = glx, gly, glz
            else:
                sbx, sby, sbz = bx, by, bz
            ox = (0.5 * (wx + lwx) - sbx) * dt
            oy = (0.5 * (wy + lwy) - sby) * dt
            oz = (0.5 * (wz + lwz) - sbz) * dt
            if gyro_delay > 0.0 and dt > 0.0:
                # a gyroscope lagging by d: its rates extrapolated linearly over the
                # accelerometer's interval, ∫ = dt (ω[i−1] + ω[i]) / 2 + d (ω[i] − ω[i−1])
                ox += gyro_delay * (wx - lwx)
                oy += gyro_delay * (wy - lwy)
                oz += gyro_delay * (wz - lwz)
            # the bias may drift (a random walk) up to its prior spread
            grow = bias_walk * bias_walk * dt
            if p00 < bias_var:
                p00 += grow
            if p11 < bias_var:
                p11 += grow
            if p22 < bias_var:
                p22 += grow
            angle = math.sqrt(ox * ox + oy * oy + oz * oz)
            if angle > 1e-12:
                c, s = math.cos(0.5 * angle), math.sin(0.5 * angle) / angle
            else:
                c, s = 1.0 - angle * angle / 8.0, 0.5 - angle * angle / 48.0
            dw, dx, dy, dz = c, s * ox, s * oy, s * oz
            gw, gx, gy, gz = (gw * dw - gx * dx - gy * dy - gz * dz,
                              gw * dx + gx * dw + gy * dz - gz * dy,
                              gw * dy - gx * dz + gy * dw + gz * dx,
                              gw * dz + gx * dy - gy * dx + gz * dw)
            n = math.sqrt(gw * gw + gx * gx + gy * gy + gz * gz)
            gw, gx, gy, gz = gw / n, gx / n, gy / n, gz / n

            # Specific force in I, low-passed by a second-order filter (ω0 = √2 / tau_acc).
            (r00, r01, r02, r10, r11,
             r12, r20, r21, r22) = quat_to_rows(gw, gx, gy, gz)
            aix = r00 * ax + r01 * ay + r02 * az
            aiy = r10 * ax + r11 * ay + r12 * az
            aiz = r20 * ax + r21 * ay + r22 * az
            # (No gating on |a|: skipping the samples that accelerate most would bias the
            # mean the low-pass forms; the filter itself rejects short knocks.)
            # Faster at rest (nothing to reject) and while the filter warms up.
            tau = tau_acc_rest if at_rest else tau_acc
            elapsed = t[i] - t_start
            if elapsed < tau:
                tau = max(elapsed, 10.0 * dt, 0.05)
            w0 = math.sqrt(2.0) / tau
            kw = w0 * w0 * dt
            kd = math.sqrt(2.0) * w0 * dt
            vx += kw * (aix - fx) - kd * vx
            vy += kw * (aiy - fy) - kd * vy
            vz += kw * (aiz - fz) - kd * vz
            fx += dt * vx
            fy += dt * vy
            fz += dt * vz
            # The tilt corrections answer the drift R (b − b_subtracted) (R: sensor → I)
            # through the same low-pass: R and R b_subtracted low-passed alike make the
            # tilt's bias equation exact in its lag (as VQF does), so that every axis of b
            # is seen as the sensor turns the horizontal through its own frame.
            d00 += kw * (r00 - l00) - kd * d00
            d01 += kw * (r01 - l01) - kd * d01
            d02 += kw * (r02 - l02) - kd * d02
            d10 += kw * (r10 - l10) - kd * d10
            d11 += kw * (r11 - l11) - kd * d11
            d12 += kw * (r12 - l12) - kd * d12
            d20 += kw * (r20 - l20) - kd * d20
            d21 += kw * (r21 - l21) - kd * d21
            d22 += kw * (r22 - l22) - kd * d22
            l00 += dt * d00
            l01 += dt * d01
            l02 += dt * d02
            l10 += dt * d10
            l11 += dt * d11
            l12 += dt * d12
            l20 += dt * d20
            l21 += dt * d21
            l22 += dt * d22
            dbx += kw * (r00 * sbx + r01 * sby + r02 * sbz - lbx) - kd * dbx
            dby += kw * (r10 * sbx + r11 * sby + r12 * sbz - lby) - kd * dby
            dbz += kw * (r20 * sbx + r21 * sby + r22 * sbz - lbz) - kd * dbz
            lbx += dt * dbx
            lby += dt * dby
            lbz += dt * dbz
            j00 += dt * l00
            j01 += dt * l01
            j02 += dt * l02
            j10 += dt * l10
            j11 += dt * l11
            j12 += dt * l12
            j20 += dt * l20
            j21 += dt * l21
            j22 += dt * l22
            zx += dt * lbx
            zy += dt * lby
            zz += dt * lbz
            tw_time += dt
            tw_turn += angle

            # Tilt: turn q_acc by the whole angle that brings the filtered force (in E) up.
            (q00, q01, q02, q10, q11,
             q12, q20, q21, q22) = quat_to_rows(cw, cx, cy, cz)
            fex = q00 * fx + q01 * fy + q02 * fz
            fey = q10 * fx + q11 * fy + q12 * fz
            fez = q20 * fx + q21 * fy + q22 * fz
            f_norm = math.sqrt(fex * fex + fey * fey + fez * fez)
            if f_norm > 0.0:
                fex, fey, fez = fex / f_norm, fey / f_norm, fez / f_norm
                h = math.sqrt(max(0.5 * (1.0 + fez), 0.0))
                if h > 1e-9:
                    ew, ex, ey = h, fey / (2.0 * h), -fex / (2.0 * h)
                    cw, cx, cy, cz = (ew * cw - ex * cx - ey * cy,
                                      ew * cx + ex * cw + ey * cz,
                                      ew * cy - ex * cz + ey * cw,
                                      ew * cz + ex * cy - ey * cx)
                    n = math.sqrt(cw * cw + cx * cx + cy * cy + cz * cz)
                    cw, cx, cy, cz = cw / n, cx / n, cy / n, cz / n
                    if not at_rest:
                        # Bias from the tilt correction: the correction (E, rad) seen in the
                        # sensor frame is the drift the bias caused (Mahony's integral term).
                        tx, ty = 2.0 * ex, 2.0 * ey  # small rotation vector, E frame
                        # E → sensor: (q_acc q_gyr)ᵀ; q_acc maps I→E, q_gyr maps sensor→I
                        ix = q00 * tx + q10 * ty
                        iy = q01 * tx + q11 * ty
                        iz = q02 * tx + q12 * ty
                        bx -= ki_bias * (r00 * ix + r10 * iy + r20 * iz)
                        by -= ki_bias * (r01 * ix + r11 * iy + r21 * iz)
                        bz -= ki_bias * (r02 * ix + r12 * iy + r22 * iz)
                        zx -= ix
                        zy -= iy
                        zz -= iz
            if at_rest or elapsed < tau_acc:
                # a rest teaches the bias itself, and the tilt's warm-up (its first tau_acc,
                # the first sample's acceleration leaving the low-pass) is no drift: the
                # window starts again after them
                tw_time = 0.0
                j00, j01, j02, j10, j11, j12, j20, j21, j22 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                                               0.0, 0.0, 0.0)
                zx, zy, zz, tw_turn = 0.0, 0.0, 0.0, 0.0
            elif tw_time >= tilt_window:
                # Over the window, in E's two horizontal axes (rows e of q_acc, I → E):
                # e·(∫LP(R) dt) b = e·(∫LP(R b_subtracted) dt − Σ corrections); each a
                # Kalman step weighed by the larger of tilt_noise² and the scatter the
                # windows' innovations show (a body's accelerations the low-pass leaves),
                # plus the drift a gyroscope's scale-factor error makes of the window's turn.
                # (Beside the integral above: that one answers at once, these windows see
                # the axes the sensor's turning shows, with their lag.)
                for row in range(2):
                    n_tw += 1.0
                    k_t = 1.0 / min(n_tw, 2.0 * mag_scatter_windows)
                    if row == 0:
                        ex, ey, ez = q00, q01, q02
                    else:
                        ex, ey, ez = q10, q11, q12
                    thx = ex * j00 + ey * j10 + ez * j20
                    thy = ex * j01 + ey * j11 + ez * j21
                    thz = ex * j02 + ey * j12 + ez * j22
                    (bx, by, bz, p00, p11, p22, p01, p02, p12,
                     scatter_t) = heading_update(bx, by, bz, p00, p11, p22, p01, p02, p12,
                                                 thx, thy, thz, ex * zx + ey * zy + ez * zz,
                                                 tilt_white + (gyro_scale * tw_turn) ** 2,
                                                 scatter_t, k_t)
                tw_time = 0.0
                j00, j01, j02, j10, j11, j12, j20, j21, j22 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                                               0.0, 0.0, 0.0)
                zx, zy, zz, tw_turn = 0.0, 0.0, 0.0, 0.0

            if has_mag == 1:
                mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
                m_norm = math.sqrt(mx * mx + my * my + mz * mz)
                # field in I, then in E
                mix = r00 * mx + r01 * my + r02 * mz
                miy = r10 * mx + r11 * my + r12 * mz
                miz = r20 * mx + r21 * my + r22 * mz
                (q00, q01, q02, q10, q11,
                 q12, q20, q21, q22) = quat_to_rows(cw, cx, cy, cz)
                mex = q00 * mix + q01 * miy + q02 * miz
                mey = q10 * mix + q11 * miy + q12 * miz
                mez = q20 * mix + q21 * miy + q22 * miz
                horizontal = math.sqrt(mex * mex + mey * mey)
                dip = math.atan2(-mez, horizontal)
                disturbed = (abs(m_norm - ref_norm) > mag_norm_tol * ref_norm
                             or abs(dip - ref_dip) > mag_dip_tol or horizontal <= 0.0)
                # The reference is the field that stays put in the earth frame while the
                # sensor turns: near a laptop or a radiator the field changes as the sensor
                # turns and moves, and a magnet on the sensor turns with it; the earth's
                # field does neither. The field in E (before the heading correction: it
                # turns only by the gyroscope's slow drift) is followed as a candidate,
                # averaged, and the turn it has held through (norm within
                # mag_norm_tolerance, direction within 2 mag_dip_tolerance) is summed; a
                # candidate that held through mag_confirm_turn of turning replaces a
                # reference that held through less. The reference's evidence also grows
                # with the time it holds (mag_hold_weight rad a second): the field a kit
                # started in on a table for a second is easily replaced, one that held
                # through half a minute is not replaced by a magnet on the sensor.
                turn = angle
                c_norm = math.sqrt(cex * cex + cey * cey + cez * cez)
                c_dot = cex * mex + cey * mey + cez * mez
                if (abs(m_norm - c_norm) > mag_norm_tol * c_norm
                        or c_dot < cos_candidate * c_norm * m_norm):
                    cex, cey, cez, cand_turn, cand_time = mex, mey, mez, 0.0, dt
                else:
                    # the running mean since the candidate began (not a low-pass, which
                    # would follow a field that turns slowly with the sensor)
                    cand_time += dt
                    k_c = dt / cand_time
                    cex += k_c * (mex - cex)
                    cey += k_c * (mey - cey)
                    cez += k_c * (mez - cez)
                    cand_turn += turn
                if not disturbed:
                    ref_turn += turn + mag_hold_weight * dt
                elif (cand_turn >= mag_confirm_turn and cand_turn > ref_turn
                      and (abs(c_norm - ref_norm) > mag_norm_tol * ref_norm
                           or abs(math.atan2(-cez, math.sqrt(cex * cex + cey * cey))
                                  - ref_dip) > mag_dip_tol)):
                    # (a candidate that is the reference, seen through the estimate's
                    # momentary tilt errors, changes nothing)
                    # a confirmed field: the new reference, and the heading starts again
                    # from the running mean of its readings
                    ref_norm = c_norm
                    ref_dip = math.atan2(-cez, math.sqrt(cex * cex + cey * cey))
                    ref_turn = cand_turn
                    disturbed = (abs(m_norm - ref_norm) > mag_norm_tol * ref_norm
                                 or abs(dip - ref_dip) > mag_dip_tol or horizontal <= 0.0)
                    jump = math.atan2(cex, cey) - delta
                    jump = (jump + math.pi) % (2.0 * math.pi) - math.pi
                    if abs(jump) > mag_restart:
                        t_mag_start = t[i]
                    disturbed_time = 0.0
                # The heading's own uncertainty grows as the gyroscope drifts about the
                # vertical: by the bias's σ along it, a MEMS bias's (bias_sigma) until a
                # rest has taught it (the field-turning windows' covariance is
                # overconfident where the field bends through space: RING's 9-axis bias
                # about z 8-18 mrad/s off with σ ~2), the covariance's once one has.
                if bias_known == 0.0:
                    sig_h += math.sqrt(bias_var) * dt
                else:
                    vux = r00 * q20 + r10 * q21 + r20 * q22
                    vuy = r01 * q20 + r11 * q21 + r21 * q22
                    vuz = r02 * q20 + r12 * q21 + r22 * q22
                    pu = (vux * vux * p00 + vuy * vuy * p11 + vuz * vuz * p22
                          + 2.0 * (vux * vuy * p01 + vux * vuz * p02 + vuy * vuz * p12))
                    sig_h += math.sqrt(max(pu, 0.0)) * dt
                if disturbed:
                    # a window of the field's turning that the disturbance spoils is dropped
                    mw_time, m_started = 0.0, 0.0
                    mVx, mVy, mVz, mYx, mYy, mYz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                    hx, hy, hz, hb, yh, s2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                    disturbed_time += dt
                    if disturbed_time > mag_reaccept:
                        ref_norm, ref_dip = m_norm, dip  # a new steady field: a new room
                        ref_turn = 0.0
                        disturbed_time = 0.0
                        t_mag_start = t[i]
                else:
                    error = math.atan2(mex, mey) - delta
                    error = (error + math.pi) % (2.0 * math.pi) - math.pi
                    # the sensor's vertical (E's z in the sensor frame: (q_acc q_gyr)ᵀ e_z)
                    ux = r00 * q20 + r10 * q21 + r20 * q22
                    uy = r01 * q20 + r11 * q21 + r21 * q22
                    uz = r02 * q20 + r12 * q21 + r22 * q22
                    if bias_known == 0.0:
                        # Bias from how the field turns in the sensor frame: for a constant
                        # field m, ω_meas × m + dm/dt = b × m. Over a window, with
                        # V = ∫m dt and Y = ∫ω×m dt + Δm: b × V = Y, two equations in b
                        # (none along V), free of any acceleration. Each window updates b
                        # by a Kalman step with the bias's covariance P: the part of b
                        # along the field, seen only as far as the field turns in the
                        # sensor (a swaying trunk's: by degrees), moves only as much as
                        # that turning outweighs the window's noise. The heading gives a
                        # second equation in the same window: the drift about the
                        # vertical, u·(b_estimate − b), is what the heading corrections
                        # took out plus the change of the error they left (the tilt
                        # corrections, which answer a horizontal drift, turn the heading
                        # too: the part of b along the field shows there).
                        # (Only until a rest has taught the bias: a rest's mean is worth
                        # more than minutes of turning field, and the filter runs faster.)
                        if m_started == 0.0:
                            m_started = 1.0
                        else:
                            # weighted by a triangle φ over the window (0 at both ends, 1 in
                            # the middle): ∫φ dm/dt dt = −∫φ' m dt takes the field's noise
                            # through φ' over the whole window, not through two samples'
                            # difference (0.07 against 0.57 µT at 0.4 µT, 60 Hz, 2 s)
                            f0 = 1.0 - abs(2.0 * mw_time / mag_window - 1.0)
                            mw_time += dt
                            f1 = max(0.0, 1.0 - abs(2.0 * mw_time / mag_window - 1.0))
                            h0, h1, hm = 0.5 * dt * f0, 0.5 * dt * f1, 0.5 * (f0 + f1)
                            mVx += h0 * lmx + h1 * mx
                            mVy += h0 * lmy + h1 * my
                            mVz += h0 * lmz + h1 * mz
                            mYx += (h0 * (lcy * lmz - lcz * lmy) + h1 * (cwy * mz - cwz * my)
                                    + hm * (mx - lmx))
                            mYy += (h0 * (lcz * lmx - lcx * lmz) + h1 * (cwz * mx - cwx * mz)
                                    + hm * (my - lmy))
                            mYz += (h0 * (lcx * lmy - lcy * lmx) + h1 * (cwx * my - cwy * mx)
                                    + hm * (mz - lmz))
                            # the heading: what the corrections took out plus the change
                            # of the remaining error is the drift about the vertical,
                            # u·(b_estimate − b) per second, weighted alike
                            de = error - last_error
                            de = (de + math.pi) % (2.0 * math.pi) - math.pi
                            yh += hm * (de + last_step)
                            hx += hm * dt * ux
                            hy += hm * dt * uy
                            hz += hm * dt * uz
                            hb += hm * dt * (ux * bx + uy * by + uz * bz)
                            s2 += (f1 - f0) * (f1 - f0)
                        lmx, lmy, lmz = mx, my, mz
                        if mw_time >= mag_window:
                            Yx, Yy, Yz = mYx, mYy, mYz
                            # The field's noise reaches both equations through φ's steps;
                            # a room's field also varies as the sensor moves (by degrees),
                            # which the windows' scatter shows: each equation's noise is
                            # the larger of the two (the scatter a running mean over the
                            # windows, the last mag_scatter_windows of them).
                            n_win += 1.0
                            k_w = 1.0 / min(n_win, mag_scatter_windows)
                            white = mag_noise * mag_noise * s2
                            horizontal2 = max(ref_norm * math.cos(ref_dip), 1.0) ** 2
                            (nbx, nby, nbz, p00, p11, p22, p01, p02, p12,
                             scatter_f) = field_turn_update(
                                bx, by, bz, p00, p11, p22, p01, p02, p12,
                                mVx, mVy, mVz, Yx, Yy, Yz, white, scatter_f, k_w)
                            (nbx, nby, nbz, p00, p11, p22, p01, p02, p12,
                             scatter_h) = heading_update(
                                nbx, nby, nbz, p00, p11, p22, p01, p02, p12,
                                hx, hy, hz, hb - yh, white / horizontal2, scatter_h, k_w)
                            if not at_rest:
                                bx, by, bz = nbx, nby, nbz
                            mw_time = 0.0
                            mVx, mVy, mVz, mYx, mYy, mYz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                            hx, hy, hz, hb, yh, s2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                    disturbed_time = 0.0
                    k_ref = dt / (tau_mag_ref + dt)
                    ref_norm += k_ref * (m_norm - ref_norm)
                    ref_dip += k_ref * (dip - ref_dip)
                    # warming up, the heading is the running mean of the first readings
                    tau_m = min(tau_mag, max(t[i] - t_mag_start, dt, 1e-3))
                    k_h = dt / (tau_m + dt)
                    # a heading whose drift since the field was last clean outweighs what
                    # one reading tells (the field's accepted deviation over its horizontal
                    # part, one independent reading per tau_mag) takes it at a Kalman gain
                    r_h = ((mag_norm_tol / max(math.cos(ref_dip), 0.05)) ** 2
                           * tau_mag / max(dt, 1e-6))
                    v_h = sig_h * sig_h
                    k_k = v_h / (v_h + r_h)
                    if k_k > k_h:
                        k_h = k_k
                    sig_h = math.sqrt(v_h * (1.0 - k_h))
                    step = k_h * error
                    delta += step
                    last_error, last_step = error, step
                    if not at_rest:
                        # the heading step is the drift about E's vertical; in the sensor
                        # frame that axis is (q_acc q_gyr)ᵀ e_z. After a rest the steps are
                        # mostly the field's own errors (its direction varies through a
                        # room; a tilt error turns its horizontal part by tan(dip) times as
                        # much), not the bias's: the gain grows back with the time since the
                        # rest, as the bias's variance does (a random walk's).
                        # (Before any rest at full gain, beside the windows' Kalman steps,
                        # which see the same drift only every mag_window seconds.)
                        k_m = ki_bias_mag
                        if bias_known != 0.0:
                            since = t[i] - last_rest
                            k_m = ki_bias_mag * since / (since + mag_bias_half_time)
                        bx -= k_m * step * ux
                        by -= k_m * step * uy
                        bz -= k_m * step * uz

            if bx > bias_max:
                bx = bias_max
            elif bx < -bias_max:
                bx = -bias_max
            if by > bias_max:
                by = bias_max
            elif by < -bias_max:
                by = -bias_max
            if bz > bias_max:
                bz = bias_max
            elif bz < -bias_max:
                bz = -bias_max

        # Output q = Rz(δ) ⊗ q_acc ⊗ q_gyr
        ow = cw * gw - cx * gx - cy * gy - cz * gz
        ox = cw * gx + cx * gw + cy * gz - cz * gy
        oy = cw * gy - cx * gz + cy * gw + cz * gx
        oz = cw * gz + cx * gy - cy * gx + cz * gw
        hc, hs = math.cos(0.5 * delta), math.sin(0.5 * delta)
        out_q[i, 0] = hc * ow - hs * oz
        out_q[i, 1] = hc * ox - hs * oy
        out_q[i, 2] = hc * oy + hs * ox
        out_q[i, 3] = hc * oz + hs * ow
        out_bias[i, 0], out_bias[i, 1], out_bias[i, 2] = bx, by, bz
        out_rest[i] = at_rest
        lwx, lwy, lwz = wx, wy, wz
        lcx, lcy, lcz = cwx, cwy, cwz
        out_disturbed[i] = disturbed

    state[0], state[1], state[2], state[3] = gw, gx, gy, gz
    state[4], state[5], state[6], state[7] = cw, cx, cy, cz
    state[8] = delta
    state[9], state[10], state[11] = bx, by, bz
    state[12] = t_last
    state[13] = initialised
    state[14] = still_time
    state[15], state[16], state[17] = glx, gly, glz
    state[18], state[19], state[20] = alx, aly, alz
    state[21], state[22], state[23] = fx, fy, fz
    state[24], state[25], state[26] = vx, vy, vz
    state[27], state[28] = ref_norm, ref_dip
    state[29] = disturbed_time
    state[167] = sig_h
    state[30], state[31], state[32], state[33] = sx, sy, sz, count
    state[34], state[35], state[36], state[37], state[38] = px, py, pz, pending, pending_time
    state[39], state[40], state[41] = lwx, lwy, lwz
    state[42] = t_start
    state[43] = bias_known
    state[44], state[45], state[46], state[47], state[48], state[49] = mVx, mVy, mVz, mYx, mYy, mYz
    state[50], state[51], state[52], state[53] = hx, hy, hz, mw_time
    state[54], state[55], state[56], state[57], state[58], state[59] = p00, p11, p22, p01, p02, p12
    state[60], state[61], state[62] = hb, yh, last_error
    state[82], state[83], state[84] = learnt_how, learnt_at, learnt_still
    state[85], state[86] = last_step, s2
    state[87], state[88], state[89] = scatter_f, scatter_h, n_win
    state[63], state[64], state[65], state[66] = lmx, lmy, lmz, m_started
    state[67], state[68], state[69] = srx, sry, srz
    state[70], state[71], state[72], state[73], state[74] = cex, cey, cez, cand_turn, ref_turn
    state[75], state[76] = t_mag_start, cand_time
    state[77] = evidence
    state[78], state[79], state[80] = afx, afy, afz
    state[81] = last_rest
    (state[90], state[91], state[92], state[93], state[94], state[95], state[96], state[97],
     state[98]) = l00, l01, l02, l10, l11, l12, l20, l21, l22
    (state[99], state[100], state[101], state[102], state[103], state[104], state[105],
     state[106], state[107]) = d00, d01, d02, d10, d11, d12, d20, d21, d22
    state[108], state[109], state[110], state[111], state[112], state[113] = (lbx, lby, lbz,
                                                                              dbx, dby, dbz)
    (state[114], state[115], state[116], state[117], state[118], state[119], state[120],
     state[121], state[122]) = j00, j01, j02, j10, j11, j12, j20, j21, j22
    state[123], state[124], state[125], state[126], state[127], state[128] = (zx, zy, zz, tw_time,
                                                                              scatter_t, n_tw)
    state[129] = tw_turn
    state[130], state[131], state[132] = b0x, b0y, b0z
    state[133], state[134], state[135] = qax, qay, qaz
    state[136], state[137], state[138], state[139] = a0x, a0y, a0z, a0t
    state[140], state[141], state[142], state[143] = a1x, a1y, a1z, a1t
    (state[144], state[145], state[146], state[147], state[148],
     state[149]) = w0x, w0y, w0z, w1x, w1y, w1z
    state[150], state[151], state[152] = qa2, va0, va1
    state[153], state[154], state[155] = lcx, lcy, lcz
    state[156] = still_dev2
    state[157], state[158], state[159] = hpx, hpy, hpz
    return -1


def append_rows_python(rows, has_mag, params, state, t_out, acc_out, gyr_out, q_out, end):
    """``kernel`` over a block of stream rows ``[t, ax, ay, az, gx, gy, gz, mx, my, mz]``
    (n, 10), the outputs' quaternions and the rows' t, acc, gyr then written at ``end`` of
    a track's buffers (``t_out`` (cap,), ``acc_out``/``gyr_out`` (cap, 3), ``q_out``
    (cap, 4)). The same inputs reach ``kernel`` as through ``update`` of the columns, so
    the same numbers; one compiled call per message of a live stream instead of a dozen
    array calls around one. Returns ``kernel``'s −1 or, having written nothing, the
    index of the first bad time."""
    n = rows.shape[0]
    t = np.empty(n)
    acc = np.empty((n, 3))
    gyr = np.empty((n, 3))
    mag = np.empty((n if has_mag else 0, 3))
    for i in range(n):
        t[i] = rows[i, 0]
        for j in range(3):
            acc[i, j] = rows[i, 1 + j]
            gyr[i, j] = rows[i, 4 + j]
            if has_mag:
                mag[i, j] = rows[i, 7 + j]
    q = np.empty((n, 4))
    bias = np.empty((n, 3))
    rest = np.zeros(n, dtype=np.bool_)
    disturbed = np.zeros(n, dtype=np.bool_)
    bad = kernel(t, acc, gyr, mag, has_mag, params, state, q, bias, rest, disturbed)
    if bad >= 0:
        return bad
    for i in range(n):
        t_out[end + i] = t[i]
        for j in range(3):
            acc_out[end + i, j] = acc[i, j]
            gyr_out[end + i, j] = gyr[i, j]
        for j in range(4):
            q_out[end + i, j] = q[i, j]
    return -1


def _compile():
    jit = compiler(nogil=True)
    if jit is None:  # the pure-Python fallback: same numbers, slower
        return kernel_python, None, False
    return jit(kernel_python), jit(append_rows_python), True


#: ``append_rows``: None without numba (the track then feeds the columns to ``update``).
kernel, append_rows, COMPILED = _compile()

EMPTY_MAG = np.zeros((0, 3))
