"""Magnetometer hard-iron offsets from a period in which the sensor is turned about.

A hard-iron offset ``o`` (a magnetised part on the board) adds to every reading in the
sensor frame: ``m = R_sensorᵀ B + o``. Turned through many orientations, the readings lie
on a sphere of radius ``|B|`` about ``o``.

* ``minmax_offset`` — the seed paper's method (Tsilomitrou et al. 2021, §3.1): the centre
  of each axis's range, ``(max + min) / 2``. Needs the sensor turned so each axis points
  both along and against the field.
* ``sphere_fit_offset`` — a linear least-squares sphere fit: ``|m|² = 2 m·o + (r² − |o|²)``
  is linear in ``(o, r² − |o|²)``; works from partial coverage too, and reports the
  radius and the rms residual [µT] as a quality figure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument, InvalidShape


@dataclass(frozen=True)
class SphereFit:
    """Hard-iron ``offset`` [µT] (3,), field ``radius`` [µT], and the rms distance of the
    readings from the fitted sphere, ``rms_residual`` [µT]."""

    offset: np.ndarray
    radius: float
    rms_residual: float


def _check(mag: np.ndarray, least: int) -> np.ndarray:
    mag = np.asarray(mag, dtype=float)
    if mag.ndim != 2 or mag.shape[1] != 3:
        raise InvalidShape(f"mag must have shape (N, 3), got {mag.shape}")
    if len(mag) < least:
        raise InvalidArgument(f"a hard-iron calibration needs at least {least} readings, "
                              f"got {len(mag)}")
    return mag


def minmax_offset(mag: np.ndarray) -> np.ndarray:
    """The seed paper's hard-iron offset [µT]: the middle of each axis's range."""
    mag = _check(mag, 2)
    return 0.5 * (mag.max(axis=0) + mag.min(axis=0))


def sphere_fit_offset(mag: np.ndarray) -> SphereFit:
    """Least-squares sphere through the readings ``mag`` [µT] (N, 3)."""
    mag = _check(mag, 4)
    A = np.column_stack([2.0 * mag, np.ones(len(mag))])
    b = np.sum(mag * mag, axis=1)
    solution, *_ = np.linalg.lstsq(A, b, rcond=None)
    offset = solution[:3]
    radius_sq = solution[3] + offset @ offset
    if not radius_sq > 0:
        raise InvalidArgument("the readings do not span a sphere: turn the sensor through "
                              "more orientations")
    radius = float(np.sqrt(radius_sq))
    residual = np.linalg.norm(mag - offset, axis=1) - radius
    return SphereFit(offset=offset, radius=radius,
                     rms_residual=float(np.sqrt(np.mean(residual ** 2))))
