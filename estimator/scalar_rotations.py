"""Scalar rotation formulas for the compiled per-sample kernels (numba inlines them; without
numba they are plain Python). The array versions live in ``rotations.py``."""

from __future__ import annotations


def _quat_to_rows(w, x, y, z):
    """The rotation matrix of a unit quaternion (wxyz) as nine floats, row by row."""
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def _compile():
    try:
        import numba
    except ImportError:
        return _quat_to_rows
    return numba.njit(cache=True, inline="always")(_quat_to_rows)


quat_to_rows = _compile()
