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
headings about the vertical (the pipeline does it: ``Pipeline._apply_constraints`` turns
the arm to the mean of its sensors' headings so turned, leaving the joints' ties alone).
A rest is ``REST_MIN_S`` of stillness; its first and last ``EDGE_S`` count as motion (a
limb settles and starts below any stillness threshold); the bias at its start is the mean
of its first ``KNOT_S``, at its end the running mean of its last. Causal and per sample:
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
#: Shortest stillness that counts as a rest [s].
REST_MIN_S = 2.0
#: A rest's first and last second may still creep (below ``STILL_GYR``): they belong to
#: the motion on either side, not to the bias [s].
EDGE_S = 1.0
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
# 12:15 running mean, 15 H
STATE_SIZE = 82


def _drift_python(t, acc, gyr, q, state, prev, out):
    """The drift taken back so far ``H`` [rad] into ``out`` (N,) for the filter's ``q``
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
                if end - state[27] >= REST_MIN_S:
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
                    state[36 + i] += a * (gyr[k, i] - state[36 + i])
                    if resting <= KNOT_S:
                        state[39 + i] += gyr[k, i]
                if resting <= KNOT_S:
                    state[42] += 1.0
                if since >= REST_MIN_S and state[2] != 0.0:
                    # at rest: the gap since the knot with the bias on the line from the
                    # knot's to this rest's first KNOT_S, then the rest with its mean
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
                    state[1] = state[0] + c + rest
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
                    state[_A + 15] = state[1]
        state[30] = t[k]
        prev[0], prev[1], prev[2], prev[3] = w, x, y, z
        out[k] = state[1]


def _compile(function):
    try:
        import numba
    except ImportError:  # the pure-Python fallback: same numbers, slower
        return function
    return numba.njit(cache=True, nogil=True)(function)


drift_kernel = _compile(_drift_python)


class DriftTakeBack:
    """Per-sensor state of ``_drift_python``."""

    def __init__(self) -> None:
        self.state = np.zeros(STATE_SIZE)
        self.prev = np.zeros(4)

    def apply(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, q: np.ndarray,
              out: np.ndarray) -> None:
        """``H`` [rad] of each sample into ``out`` (N,) (see the module); contiguous
        arrays."""
        drift_kernel(t, acc, gyr, q, self.state, self.prev, out)
