"""A sensor's segment orientation at given times, compiled: slerp between the sensor's
bracketing samples (held before the first and after the last), quaternion to matrix,
then ``Rz(heading) · R_world_sensor · R_sensor_segment``. The same numbers as
``quat_slerp`` + ``quat_to_matrix`` + the heading and mounting products (to 1e-12), in one
pass instead of a dozen small numpy calls per chunk."""

from __future__ import annotations

import math

import numpy as np

from ..jit import compiler
from ..scalar_rotations import quat_to_rows


def _segment_python(t, q, times, R_sensor_segment, heading, out):
    """``t`` (M,) and ``q`` (M, 4) wxyz of the sensor; ``times`` (N,); ``out`` (N, 3, 3)."""
    m = t.shape[0]
    ch, sh = math.cos(heading), math.sin(heading)
    j = 0
    for n in range(times.shape[0]):
        tau = times[n]
        while j + 1 < m and t[j + 1] <= tau:
            j += 1
        if tau < t[0]:
            j = 0
        k = j + 1 if j + 1 < m else j
        span = t[k] - t[j]
        u = (tau - t[j]) / span if span > 0.0 else 0.0
        u = min(max(u, 0.0), 1.0)
        aw, ax, ay, az = q[j, 0], q[j, 1], q[j, 2], q[j, 3]
        bw, bx, by, bz = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        dot = aw * bw + ax * bx + ay * by + az * bz
        if dot < 0.0:
            bw, bx, by, bz, dot = -bw, -bx, -by, -bz, -dot
        dot = min(dot, 1.0)
        if u == 0.0:  # at a sample's own time (the reference's, or a shared stamp):
            w0, w1 = 1.0, 0.0  # sin(θ)/sin(θ) and sin(0)/sin(θ), exactly, without them
        else:
            theta = math.acos(dot)
            s = math.sin(theta)
            if s < 1e-9:
                w0, w1 = 1.0 - u, u
            else:
                w0, w1 = math.sin((1.0 - u) * theta) / s, math.sin(u * theta) / s
        w, x, y, z = w0 * aw + w1 * bw, w0 * ax + w1 * bx, w0 * ay + w1 * by, w0 * az + w1 * bz
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        (r00, r01, r02, r10, r11,
         r12, r20, r21, r22) = quat_to_rows(w, x, y, z)
        # Rz(heading) · R
        h00, h01, h02 = ch * r00 - sh * r10, ch * r01 - sh * r11, ch * r02 - sh * r12
        h10, h11, h12 = sh * r00 + ch * r10, sh * r01 + ch * r11, sh * r02 + ch * r12
        for c in range(3):
            s0, s1, s2 = R_sensor_segment[0, c], R_sensor_segment[1, c], R_sensor_segment[2, c]
            out[n, 0, c] = h00 * s0 + h01 * s1 + h02 * s2
            out[n, 1, c] = h10 * s0 + h11 * s1 + h12 * s2
            out[n, 2, c] = r20 * s0 + r21 * s1 + r22 * s2


def _compile():
    jit = compiler(nogil=True)
    return jit(_segment_python) if jit else _segment_python


_segment = _compile()


def segment_orientations(t: np.ndarray, q: np.ndarray, times: np.ndarray,
                         R_sensor_segment: np.ndarray, heading: float,
                         out: np.ndarray | None = None) -> np.ndarray:
    """``R_world_segment`` (N, 3, 3) at ``times`` [s] (N,), increasing; written into
    ``out`` when given (it may be a strided view)."""
    if out is None:
        out = np.empty((len(times), 3, 3))
    if len(times):
        _segment(np.ascontiguousarray(t), np.ascontiguousarray(q),
                 np.ascontiguousarray(times), np.ascontiguousarray(R_sensor_segment),
                 float(heading), out)
    return out
