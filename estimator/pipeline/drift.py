"""A 6-axis sensor's heading drift between two rests, taken back at the second one.

Without a magnetometer a sensor's heading is the integral of its gyroscope's vertical
rate less the filter's bias, and nothing corrects it. A rest holds the heading and shows
the bias (the mean of the gyroscope at rest), but the bias's random walk during the motion
before it has already turned the heading. Between two rests the bias is best taken as the
line from the first rest's mean to the second's (a random walk pinned at both ends: its
expected path; the heading's variance then ``q²T³/12`` against ``q²T³/3`` for the first
rest's bias held, ``q`` the walk [rad/s/√s], ``T`` the motion [s]). At the second rest the
heading the filter turned with its own bias is replaced by the one that line gives::

    H += ∫ (b_filter − b_line(t)) · z dt

``z`` the world's vertical in the sensor frame; ``b_filter · z`` the filter's vertical bias,
read from its orientations (the gyroscope's vertical rate less the orientations' own: the
tilt corrections turn about horizontal axes). ``H`` [rad] turns the sensor's later
headings about the vertical (the pipeline turns each segment by its sensor's before the
joints tie them). A rest is ``REST_MIN_S`` of stillness — the pause between two
repetitions is one, and the more rests the shorter each stretch of the walk left to the
line — its first and last ``EDGE_S`` count as motion (a limb settles and starts below any
stillness threshold); one shorter than ``LONG_REST_S`` counts only where its mean is near
the last rest's bias and known well (a steady turn is as steady as a rest for a second);
the bias at its start is the mean of its first ``KNOT_S``, at its end the running mean of
its last. Each mean is a measurement with its variance, not the truth: the knots feed a
Kalman filter of the bias ``b`` and the heading integral ``I = ∫b·z dt`` (the walk ``q`` is
the filter's own ``QcfParams.bias_walk``): between knots ``P_bb`` grows by ``q²`` a second
and ``P_Ib`` by ``P_bb z dt``; at a rest its first ``KNOT_S`` mean (variance: the rest's own
scatter over its samples) is one step, whose heading part
``P_Ib S⁻¹ ν`` takes the line's place — with exact knots it is the line; a short pause at
50 Hz (0.8 mrad/s) moves the heading and the next knot's bias only by what it is worth
(per-sensor heading RMS on simulated 11-min sessions, seeds 1–16: 1.21 → 1.14°). A long
rest's knot (its last ``KNOT_S``'s running mean) carries that mean's noise. (Adding the
walk within a mean's span to its variance, which a bias constant at rests does not have,
breaks the exact take-back of a noise-free knot: tests/test_drift_take_back.py.) Causal
and per sample:
any chunking gives the same. Only for 6-axis sensors (``SensorTrack``); a 9-axis heading
has the magnetometer.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import compiler
from ..orientation.qcf import QcfParams
from ..scalar_linalg import sym3_adjugate

#: Deviation from the run's mean that still counts as still: gyroscope [rad/s],
#: accelerometer [m/s²].
STILL_GYR = 0.03
STILL_ACC = 0.3
#: Shortest stillness that counts as a rest [s]: the pause between two repetitions (about
#: a second) shows the bias as well as a rest between sets, and the shorter the gaps
#: between rests the less of the walk is left (per-sensor heading RMS on simulated 11-min
#: sessions, seeds 1–12: 3.03° with 2 s, 1.03° with 0.8 s; 0.5–1.0 s all 1.0–1.5°).
REST_MIN_S = 0.8
#: A rest's first and last moments may still creep (below ``STILL_GYR``): they belong to
#: the motion on either side, not to the bias [s].
EDGE_S = 0.2
#: A stillness shorter than this is a rest only where its mean is within ``STILL_BIAS``
#: [rad/s] of the last rest's bias: a turn at a steady rate (the middle of a slow swing)
#: is as steady as a rest for a second, but shows its rate, not the bias [s].
LONG_REST_S = 2.0
STILL_BIAS = 0.005
#: ... and where its mean shows the bias to this [rad/s] (its standard error per axis, from
#: its own scatter): a short pause of a noisy gyroscope (a phone's, 0.01 rad/s at 60 Hz:
#: 1.7 mrad/s over 0.6 s) adds more error at each knot than the walk it takes back.
STILL_ERROR = 0.001
#: The bias at a rest's ends is the mean over this long [s] (the walk within it against
#: the noise: a sweep on simulated sessions, 2.5 s to the whole rest, chose 8 s).
KNOT_S = 8.0
#: The bias's random walk [rad/s/√s]: the filter's own figure (``QcfParams.bias_walk``).
BIAS_WALK = QcfParams.bias_walk
#: False: the tracks leave the filter's headings as they are (for comparisons).
ENABLED = True
# state layout: 0 H at the last knot, 1 H, 2 has a knot, 3 t0 (the knot's time),
# 4:7 b0 (its bias), 7:10 Z0 = ∫z dt, 10:13 Z1 = ∫(t − t0) z dt, 13 U = ∫b_filter·z dt
# (since the knot); 14 the rest's first time, 15 the run's last time; the rest (the run
# past EDGE_S): 16:19 Z0, 19:22 Z1, 22 U, 43:46 gyr sum, 46 count, 36:39 running mean of
# its last KNOT_S, 39:42 gyr sum of its first KNOT_S, 42 count; the run: 23:26 gyr sum,
# 26 count, 27 start, 32:35 acc sum; 30 the previous time, 31 started; checkpoints of the
# rest every EDGE_S: the last at 50, the one before at 66 (CHECKPOINT fields).
_A, _B = 50, 66
# checkpoint fields: 0 time (NaN: none), 1:4 Z0, 4:7 Z1, 7 U, 8:11 gyr sum, 11 count,
# 12:15 running mean, 15 H; 82 the rest's sum of squared gyro [rad²/s²]; the Kalman
# bookkeeping of the bias b and the heading integral I = ∫b·z dt: 83:89 P_bb at the knot
# (xx, yy, zz, xy, xz, yz) [rad²/s²], 89:92 P_Ib there [rad²/s]; this rest's candidate
# (what a knot here keeps): 92:95 b, 95:101 P_bb, 101:104 P_Ib; the checkpoints' copies
# of the candidate at _A2 and _B2 (12 each)
_A2, _B2 = 104, 116
STATE_SIZE = 128


def _mean_variance_python(state, n):
    """The variance per axis of a mean of ``n`` of this rest's samples [rad²/s²]: their
    scatter (the rest's own, ``STILL_ERROR``² a sample while it has under two) over ``n``."""
    count = state[46]
    if count < 2.0 or n < 1.0:
        return STILL_ERROR * STILL_ERROR
    square = state[82]
    for i in range(3):
        mean = state[43 + i] / count
        square -= count * mean * mean
    return max(square, 0.0) / (3.0 * (count - 1.0)) / n


def _set_knot_covariance_python(state, r):
    """A knot whose bias is a mean of variance ``r`` per axis, the heading's error then
    independent of it."""
    state[83], state[84], state[85] = r, r, r
    for j in range(86, 92):
        state[j] = 0.0


def _gap_step_python(state, gap):
    """The heading integral ∫b·z dt over the gap from the knot to this rest [rad], and
    this rest's candidate (b, P_bb, P_Ib at 92:104): one Kalman step of the state (b, I)
    with the mean of the rest's first ``KNOT_S`` (its variance from the rest's scatter)
    against the knot's bias grown by the walk over the gap. With an exact knot and mean it
    is the line between them (``∫(b0 + (b1 − b0)(t − t0)/gap)·z dt``); a noisy short pause
    counts less, in the bias and in the heading."""
    q2 = BIAS_WALK * BIAS_WALK
    r = _mean_variance(state, state[42])
    walk = q2 * gap
    # the prior at the rest's start: P_bb = P0 + q² gap, P_Ib = P_Ib0 + P0 Z0 + q² Z1
    z0x = state[7] - state[16]
    z0y = state[8] - state[17]
    z0z = state[9] - state[18]
    z1x = state[10] - state[19]
    z1y = state[11] - state[20]
    z1z = state[12] - state[21]
    p00, p11, p22 = state[83], state[84], state[85]
    p01, p02, p12 = state[86], state[87], state[88]
    ix = state[89] + p00 * z0x + p01 * z0y + p02 * z0z + q2 * z1x
    iy = state[90] + p01 * z0x + p11 * z0y + p12 * z0z + q2 * z1y
    iz = state[91] + p02 * z0x + p12 * z0y + p22 * z0z + q2 * z1z
    p00 += walk
    p11 += walk
    p22 += walk
    # S = P_bb + r, its inverse (symmetric, positive definite)
    c00, c01, c02, c11, c12, c22, det = sym3_adjugate(p00 + r, p11 + r, p22 + r,
                                                      p01, p02, p12)
    nx = state[39] / state[42] - state[4]
    ny = state[40] / state[42] - state[5]
    nz = state[41] / state[42] - state[6]
    integral = state[4] * z0x + state[5] * z0y + state[6] * z0z
    if not det > 0.0:
        for i in range(3):
            state[92 + i] = state[4 + i]
        return integral
    f = 1.0 / det
    # u = S⁻¹ ν; the heading's step P_Ib · u, the bias's P_bb u
    ux = (c00 * nx + c01 * ny + c02 * nz) * f
    uy = (c01 * nx + c11 * ny + c12 * nz) * f
    uz = (c02 * nx + c12 * ny + c22 * nz) * f
    integral += ix * ux + iy * uy + iz * uz
    state[92] = state[4] + p00 * ux + p01 * uy + p02 * uz
    state[93] = state[5] + p01 * ux + p11 * uy + p12 * uz
    state[94] = state[6] + p02 * ux + p12 * uy + p22 * uz
    # P_bb −= P_bb S⁻¹ P_bb, P_Ib −= P_bb S⁻¹ P_Ib (W = P_bb S⁻¹, rows)
    w00 = (p00 * c00 + p01 * c01 + p02 * c02) * f
    w01 = (p00 * c01 + p01 * c11 + p02 * c12) * f
    w02 = (p00 * c02 + p01 * c12 + p02 * c22) * f
    w10 = (p01 * c00 + p11 * c01 + p12 * c02) * f
    w11 = (p01 * c01 + p11 * c11 + p12 * c12) * f
    w12 = (p01 * c02 + p11 * c12 + p12 * c22) * f
    w20 = (p02 * c00 + p12 * c01 + p22 * c02) * f
    w21 = (p02 * c01 + p12 * c11 + p22 * c12) * f
    w22 = (p02 * c02 + p12 * c12 + p22 * c22) * f
    state[95] = p00 - (w00 * p00 + w01 * p01 + w02 * p02)
    state[96] = p11 - (w10 * p01 + w11 * p11 + w12 * p12)
    state[97] = p22 - (w20 * p02 + w21 * p12 + w22 * p22)
    state[98] = p01 - (w00 * p01 + w01 * p11 + w02 * p12)
    state[99] = p02 - (w00 * p02 + w01 * p12 + w02 * p22)
    state[100] = p12 - (w10 * p02 + w11 * p12 + w12 * p22)
    state[101] = ix - (w00 * ix + w01 * iy + w02 * iz)
    state[102] = iy - (w10 * ix + w11 * iy + w12 * iz)
    state[103] = iz - (w20 * ix + w21 * iy + w22 * iz)
    return integral


def _is_rest_python(state, length, n):
    """Whether a still run of ``length`` [s] (``n`` samples) is a rest (``LONG_REST_S``)."""
    if length >= LONG_REST_S:
        return True
    if state[2] == 0.0 or state[46] < 2.0:
        return False
    off = 0.0
    square = state[82]
    for i in range(3):
        mean = state[43 + i] / state[46]
        off += (mean - state[4 + i]) ** 2
        square -= state[46] * mean * mean
    # the mean's standard error per axis, from the rest's own scatter
    error2 = max(square, 0.0) / (3.0 * (state[46] - 1.0) * state[46])
    return off < STILL_BIAS * STILL_BIAS and error2 < STILL_ERROR * STILL_ERROR


def _drift_python(t, acc, gyr, q, state, prev, out):
    """The drift taken back so far ``H`` [rad] into ``out[:, 0]`` and the time [s] of the
    knot the drift not yet taken back counts from into ``out[:, 1]`` (NaN: no knot yet)
    (``out`` (N, 2)) for the filter's ``q``
    (N, 4) wxyz ``R_world_sensor`` of samples ``t`` [s], ``acc``, ``gyr`` [rad/s]:
    the sensor's heading is ``Rz(H) · R(q)``. ``state`` (STATE_SIZE,) and ``prev`` (4,)
    the last q carry over between chunks."""
    for k in range(t.shape[0]):
        w, x, y, z = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        # world vertical in the sensor frame: the third row of R
        zx = 2.0 * (x * z - w * y)
        zy = 2.0 * (y * z + w * x)
        zz = 1.0 - 2.0 * (x * x + y * y)
        if state[31] == 0.0:
            state[31] = 1.0
            state[_A] = math.nan
            state[_B] = math.nan
            state[27] = t[k]
            state[15] = t[k]
            for i in range(3):
                state[23 + i] = gyr[k, i]
                state[32 + i] = acc[k, i]
            state[26] = 1.0
        else:
            dt = t[k] - state[30]
            pw, px, py, pz = prev[0], -prev[1], -prev[2], -prev[3]  # conjugate
            rw = pw * w - px * x - py * y - pz * z
            rx = pw * x + px * w + py * z - pz * y
            ry = pw * y - px * z + py * w + pz * x
            rz = pw * z + px * y - py * x + pz * w
            if rw < 0.0:
                rw, rx, ry, rz = -rw, -rx, -ry, -rz
            s = math.sqrt(rx * rx + ry * ry + rz * rz)
            own = 0.0
            if s > 0.0:  # the orientations' own vertical turn [rad]
                own = 2.0 * math.atan2(s, rw) * (rx * zx + ry * zy + rz * zz) / s
            # the filter's vertical bias × dt: what the gyroscope turned and it did not
            wdt = (gyr[k, 0] * zx + gyr[k, 1] * zy + gyr[k, 2] * zz) * dt - own
            n = state[26]
            dg = 0.0
            da = 0.0
            for i in range(3):
                dg += (gyr[k, i] - state[23 + i] / n) ** 2
                da += (acc[k, i] - state[32 + i] / n) ** 2
            if dg >= STILL_GYR * STILL_GYR or da >= STILL_ACC * STILL_ACC:
                end = state[15]
                if end - state[27] >= REST_MIN_S and _is_rest(state, end - state[27], n):
                    # a rest ended: the knot is where it last was still for sure (a
                    # checkpoint at least EDGE_S before its end), its bias the running
                    # mean there; what came after belongs to the next gap
                    c = -1
                    if state[_A] <= end - EDGE_S:
                        c = _A
                    elif state[_B] <= end - EDGE_S:
                        c = _B
                    if c >= 0:
                        t0 = state[c]
                        state[0] = state[c + 15]
                        c2 = _A2 if c == _A else _B2
                        if t0 - state[14] < KNOT_S:
                            # the rest so far is one mean, weighed against the gap's
                            # line: its candidate (the rest's part to the checkpoint
                            # adds to the heading's covariance with the bias)
                            for j in range(9):
                                state[83 + j] = state[c2 + 3 + j]
                            pxx, pyy, pzz = state[c2 + 3], state[c2 + 4], state[c2 + 5]
                            pxy, pxz, pyz = state[c2 + 6], state[c2 + 7], state[c2 + 8]
                            zr0, zr1, zr2 = state[c + 1], state[c + 2], state[c + 3]
                            state[89] += pxx * zr0 + pxy * zr1 + pxz * zr2
                            state[90] += pxy * zr0 + pyy * zr1 + pyz * zr2
                            state[91] += pxz * zr0 + pyz * zr1 + pzz * zr2
                        else:  # the running mean of its last KNOT_S alone
                            r = _mean_variance(state, state[c + 11])
                            if state[c + 11] > 1.0:
                                step = (t0 - state[14]) / (state[c + 11] - 1.0)
                                alpha = min(step / KNOT_S, 1.0)
                                r = _mean_variance(state, 1.0) * alpha / (2.0 - alpha)
                            _set_knot_covariance(state, r)
                        for i in range(3):
                            if t0 - state[14] < KNOT_S:
                                state[4 + i] = state[c2 + i]
                            else:
                                state[4 + i] = state[c + 12 + i]
                            z0 = state[16 + i] - state[c + 1 + i]
                            z1 = state[19 + i] - state[c + 4 + i] - (t0 - state[3]) * z0
                            state[7 + i] = z0
                            state[10 + i] = z1
                        state[13] = state[22] - state[c + 7]
                    else:  # too short for its edges: its mean at its end
                        t0 = end
                        state[0] = state[1]
                        _set_knot_covariance(state, STILL_ERROR * STILL_ERROR)
                        for i in range(3):
                            state[4 + i] = state[36 + i] if state[46] > 0.0 \
                                else state[23 + i] / n
                            state[7 + i] = 0.0
                            state[10 + i] = 0.0
                        state[13] = 0.0
                    state[1] = state[0]
                    state[2] = 1.0
                    state[3] = t0
                # a new run from this sample
                for i in range(3):
                    state[16 + i] = 0.0
                    state[19 + i] = 0.0
                    state[23 + i] = 0.0
                    state[32 + i] = 0.0
                    state[39 + i] = 0.0
                    state[43 + i] = 0.0
                state[22] = 0.0
                state[26] = 0.0
                state[42] = 0.0
                state[46] = 0.0
                state[82] = 0.0
                state[27] = t[k]
                state[_A] = math.nan
                state[_B] = math.nan
            tau = t[k] - state[3]
            since = t[k] - state[27]
            for i in range(3):
                zs = (zx, zy, zz)[i] * dt
                state[7 + i] += zs
                state[10 + i] += tau * zs
                state[23 + i] += gyr[k, i]
                state[32 + i] += acc[k, i]
            state[13] += wdt
            state[26] += 1.0
            state[15] = t[k]
            if since >= EDGE_S:  # the rest proper
                if state[46] == 0.0:
                    state[14] = t[k]
                state[46] += 1.0
                state[22] += wdt
                resting = t[k] - state[14]
                a = 1.0 / state[46] if resting < KNOT_S else min(dt / KNOT_S, 1.0)
                for i in range(3):
                    zs = (zx, zy, zz)[i] * dt
                    state[16 + i] += zs
                    state[19 + i] += tau * zs
                    state[43 + i] += gyr[k, i]
                    state[82] += gyr[k, i] * gyr[k, i]
                    state[36 + i] += a * (gyr[k, i] - state[36 + i])
                    if resting <= KNOT_S:
                        state[39 + i] += gyr[k, i]
                if resting <= KNOT_S:
                    state[42] += 1.0
                taken = state[1]
                if state[2] != 0.0:
                    # the gap since the knot, then the rest with its mean: what a knot
                    # here keeps, and the output once the run is a rest (REST_MIN_S)
                    gap = state[14] - state[3]
                    c = state[13] - state[22] - _gap_step(state, gap)
                    rest = state[22]
                    for i in range(3):
                        rest -= state[43 + i] / state[46] * state[16 + i]
                    taken = state[0] + c + rest
                else:  # a first rest: its mean alone
                    r = _mean_variance(state, state[46])
                    for i in range(3):
                        state[92 + i] = state[43 + i] / state[46]
                        state[101 + i] = 0.0
                    state[95], state[96], state[97] = r, r, r
                    state[98], state[99], state[100] = 0.0, 0.0, 0.0
                if state[2] != 0.0 and since >= REST_MIN_S and _is_rest(state, since,
                                                                        state[26]):
                    state[1] = taken
                if not t[k] - state[_A] < EDGE_S:  # (NaN: no checkpoint yet)
                    for j in range(16):
                        state[_B + j] = state[_A + j]
                    state[_A] = t[k]
                    for i in range(3):
                        state[_A + 1 + i] = state[16 + i]
                        state[_A + 4 + i] = state[19 + i]
                        state[_A + 8 + i] = state[43 + i]
                        state[_A + 12 + i] = state[36 + i]
                    state[_A + 7] = state[22]
                    state[_A + 11] = state[46]
                    state[_A + 15] = taken
                    for j in range(12):
                        state[_B2 + j] = state[_A2 + j]
                        state[_A2 + j] = state[92 + j]
        state[30] = t[k]
        prev[0], prev[1], prev[2], prev[3] = w, x, y, z
        out[k, 0] = state[1]
        out[k, 1] = state[3] if state[2] != 0.0 else math.nan


def _compile(function):
    jit = compiler(nogil=True)
    return jit(function) if jit else function


def _taken_at_python(t, h, times, R, out):
    """At each of ``times`` [s] (M,), non-decreasing: the drift taken back [rad]
    interpolated in time as ``np.interp(times, t, h[:, 0])`` does (the same numbers) into
    ``out[:, 0]``, and the knot time [s] of the last sample at or before it (the first
    sample before ``t[0]``) into ``out[:, 1]``; ``R`` (M, 3, 3) ``R_world_segment`` turned
    in place about the world's vertical by the drift taken back (``Rz(H) · R``). ``t`` [s]
    (N,) and ``h`` (N, 2) (``H``, knot) are a track's samples (``_drift_python``'s
    output). One pass instead of a search, an interpolation and a turn per chunk."""
    m = t.shape[0]
    j = 0
    last, c, s = 0.0, 1.0, 0.0
    for n in range(times.shape[0]):
        x = times[n]
        while j + 1 < m and t[j + 1] <= x:
            j += 1
        # np.interp: held at either end, a sample's own value at its time, else the line
        if x >= t[m - 1] or j == m - 1:
            value = h[m - 1, 0]
        elif x < t[0] or x == t[j]:
            value = h[0, 0] if x < t[0] else h[j, 0]
        else:
            slope = (h[j + 1, 0] - h[j, 0]) / (t[j + 1] - t[j])
            value = slope * (x - t[j]) + h[j, 0]
            if math.isnan(value):
                value = slope * (x - t[j + 1]) + h[j + 1, 0]
                if math.isnan(value) and h[j, 0] == h[j + 1, 0]:
                    value = h[j, 0]
        out[n, 0] = value
        out[n, 1] = h[j, 1]
        if value != 0.0:
            if value != last:  # H holds between knots: its sine and cosine too
                last, c, s = value, math.cos(value), math.sin(value)
            for k in range(3):
                r0, r1 = R[n, 0, k], R[n, 1, k]
                R[n, 0, k] = c * r0 - s * r1
                R[n, 1, k] = s * r0 + c * r1


_mean_variance = _compile(_mean_variance_python)
_set_knot_covariance = _compile(_set_knot_covariance_python)
_gap_step = _compile(_gap_step_python)
_is_rest = _compile(_is_rest_python)
drift_kernel = _compile(_drift_python)
taken_at = _compile(_taken_at_python)


class DriftTakeBack:
    """Per-sensor state of ``_drift_python``."""

    def __init__(self) -> None:
        self.state = np.zeros(STATE_SIZE)
        self.prev = np.zeros(4)

    def apply(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, q: np.ndarray,
              out: np.ndarray) -> None:
        """``H`` [rad] of each sample and its knot's time [s] into ``out`` (N, 2) (see
        ``_drift_python``); row-contiguous arrays."""
        drift_kernel(t, acc, gyr, q, self.state, self.prev, out)
