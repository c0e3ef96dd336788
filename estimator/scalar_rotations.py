"""Scalar rotation formulas for the compiled per-sample kernels (numba inlines them; without
numba they are plain Python). The array versions live in ``rotations.py``."""

from __future__ import annotations

from .jit import compiler


def _quat_to_rows(w, x, y, z):
    """The rotation matrix of a unit quaternion (wxyz) as nine floats, row by row."""
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def quat_from_rows(m00, m01, m02, m10, m11, m12, m20, m21, m22):
    """The unit quaternion (wxyz, w ≥ 0; when w = 0 the first non-zero component > 0) of a
    rotation matrix given row by row. Shepperd's method: the largest of the four diagonal
    combinations is the pivot, so it is accurate for every rotation. Plain Python: a few
    µs for one matrix, where an array call costs tens (``rotations.matrix_to_quat``)."""
    trace = m00 + m11 + m22
    if trace >= m00 and trace >= m11 and trace >= m22:
        r = (1.0 + trace) ** 0.5
        f = 0.5 / r
        q = (0.5 * r, (m21 - m12) * f, (m02 - m20) * f, (m10 - m01) * f)
    elif m00 >= m11 and m00 >= m22:
        r = (1.0 + m00 - m11 - m22) ** 0.5
        f = 0.5 / r
        q = ((m21 - m12) * f, 0.5 * r, (m01 + m10) * f, (m02 + m20) * f)
    elif m11 >= m22:
        r = (1.0 - m00 + m11 - m22) ** 0.5
        f = 0.5 / r
        q = ((m02 - m20) * f, (m01 + m10) * f, 0.5 * r, (m12 + m21) * f)
    else:
        r = (1.0 - m00 - m11 + m22) ** 0.5
        f = 0.5 / r
        q = ((m10 - m01) * f, (m02 + m20) * f, (m12 + m21) * f, 0.5 * r)
    norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) ** 0.5
    # the first non-zero component (the norm is ≥ 0.5: not all are zero)
    first = q[0] if q[0] != 0.0 else q[1] if q[1] != 0.0 else q[2] if q[2] != 0.0 else q[3]
    sign = (1.0 if first > 0 else -1.0) / norm
    return (q[0] * sign, q[1] * sign, q[2] * sign, q[3] * sign)


def _compile():
    jit = compiler(inline="always")
    return jit(_quat_to_rows) if jit else _quat_to_rows


def __getattr__(name: str):
    """``quat_to_rows``, compiled on first use: importing numba takes ~0.45 s, which the
    plain-Python ``quat_from_rows`` (``armtrack pose``, the live estimator) need not pay."""
    if name == "quat_to_rows":
        globals()["quat_to_rows"] = compiled = _compile()
        return compiled
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
