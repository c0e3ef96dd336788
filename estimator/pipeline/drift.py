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
its last. Causal and per sample:
any chunking gives the same. Only for 6-axis sensors (``SensorTrack``); a 9-axis heading
has the magnetometer.
"""

from __future__ import annotations

import math

import numpy as np

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
# 12:15 running mean, 15 H; 82 the rest's sum of squared gyro [rad²/s²]
STATE_SIZE = 83


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
                        for i in range(3):
                            state[4 + i] = state[c + 12 + i]
                            z0 = state[16 + i] - state[c + 1 + i]
                            z1 = state[19 + i] - state[c + 4 + i] - (t0 - state[3]) * z0
                            state[7 + i] = z0
                            state[10 + i] = z1
                        state[13] = state[22] - state[c + 7]
                    else:  # too short for its edges: its mean at its end
                        t0 = end
                        state[0] = state[1]
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
                    # the gap since the knot with the bias on the line from the knot's to
                    # this rest's first KNOT_S, then the rest with its mean: what a knot
                    # here keeps, and the output once the run is a rest (REST_MIN_S)
                    gap = state[14] - state[3]
                    c = state[13] - state[22]
                    rest = state[22]
                    for i in range(3):
                        b1 = state[39 + i] / state[42]
                        b0 = state[4 + i]
                        z0g = state[7 + i] - state[16 + i]
                        z1g = state[10 + i] - state[19 + i]
                        c -= b0 * z0g + (b1 - b0) * (z1g / gap if gap > 0.0 else 0.0)
                        rest -= state[43 + i] / state[46] * state[16 + i]
                    taken = state[0] + c + rest
                    if since >= REST_MIN_S and _is_rest(state, since, state[26]):
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
        state[30] = t[k]
        prev[0], prev[1], prev[2], prev[3] = w, x, y, z
        out[k, 0] = state[1]
        out[k, 1] = state[3] if state[2] != 0.0 else math.nan


def _compile(function):
    try:
        import numba
    except ImportError:  # the pure-Python fallback: same numbers, slower
        return function
    return numba.njit(cache=True, nogil=True)(function)


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
