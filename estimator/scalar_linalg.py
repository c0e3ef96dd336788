"""Scalar linear algebra for the compiled per-sample kernels (numba inlines it; without
numba it is plain Python): the qcf kernel's bias updates (``orientation.qcf_kernel``) and
the drift take-back's Kalman step (``pipeline.drift``) invert a symmetric 3×3 matrix."""

from __future__ import annotations

from .jit import compiler


def _sym3_adjugate(s00, s11, s22, s01, s02, s12):
    """The cofactors and determinant of the symmetric 3×3 matrix ``S`` given by its upper
    triangle: ``(c00, c01, c02, c11, c12, c22, det)``, ``S⁻¹ = C / det`` (``C``
    symmetric too). The caller checks ``det > 0`` (``S`` positive definite) and scales
    by ``1 / det`` where its rounding wants it."""
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    det = s00 * c00 + s01 * c01 + s02 * c02
    return c00, c01, c02, c11, c12, c22, det


def _compile():
    jit = compiler(inline="always")
    return jit(_sym3_adjugate) if jit else _sym3_adjugate


sym3_adjugate = _compile()
