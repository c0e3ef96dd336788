"""Trajectory errors between an estimate and a truth: MAE, maximum error and RMSE (seed
paper, Tsilomitrou et al. 2021, eq. 17)::

    MAE      = Σ |d_i| / n
    MaxError = max |d_i|
    RMSE     = sqrt(Σ d_i² / n)

with ``d_i`` the error of sample ``i``: ``estimate_i − truth_i`` for a 1-D series (an
angle, a coordinate), the **Euclidean distance** ``‖estimate_i − truth_i‖`` for 3-D
positions. (The paper writes its points as ``P_i = sqrt(x² + y² + z²)``; the difference of
two such norms would be blind to an error perpendicular to the position vector, so the
distance between the points is used.) No wrapping is applied: joint angles are continuous
(unwrapped) series.

Units are those of the inputs ([rad], [deg] or [m]). Samples where the estimate is NaN
(missing: lost samples, no estimate yet) are skipped and counted as ``missing``; a NaN in
the truth is an error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgument, InvalidShape


@dataclass(frozen=True)
class TrajectoryErrors:
    """Errors over the compared samples, in the inputs' unit."""

    mae: float
    max_error: float
    rmse: float
    #: Samples compared.
    samples: int
    #: Samples skipped because the estimate was missing (NaN).
    missing: int


def series_errors(estimate: np.ndarray, truth: np.ndarray) -> TrajectoryErrors:
    """Errors of a 1-D series: ``estimate`` and ``truth`` of shape (N,), same unit."""
    estimate, truth = _pair(estimate, truth, 1)
    return _summarise(estimate - truth)


def position_errors(estimate: np.ndarray, truth: np.ndarray) -> TrajectoryErrors:
    """Errors of 3-D positions: ``estimate`` and ``truth`` of shape (N, 3), same unit; the
    error of a sample is the distance between its two points. A sample whose estimate
    has any NaN coordinate is missing."""
    estimate, truth = _pair(estimate, truth, 2)
    if estimate.shape[1] != 3:
        raise InvalidShape(f"positions must have shape (N, 3), got {estimate.shape}")
    missing = np.any(np.isnan(estimate), axis=1)
    distance = np.linalg.norm(np.where(missing[:, None], 0.0, estimate) - truth, axis=1)
    return _summarise(np.where(missing, np.nan, distance))


def _pair(estimate: np.ndarray, truth: np.ndarray, ndim: int) -> tuple[np.ndarray, np.ndarray]:
    estimate = np.asarray(estimate, dtype=float)
    truth = np.asarray(truth, dtype=float)
    expected = "(N,)" if ndim == 1 else "(N, 3)"
    if estimate.ndim != ndim or truth.shape != estimate.shape:
        raise InvalidShape(f"estimate and truth must both have shape {expected}, got "
                           f"{estimate.shape} and {truth.shape}")
    if not np.all(np.isfinite(truth)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(truth.reshape(truth.shape[0], -1)),
                                         axis=1))[0])
        raise InvalidArgument(f"truth must be finite; sample {bad} is {truth[bad]!r}")
    if np.any(np.isinf(estimate)):
        raise InvalidArgument("estimate must be finite or NaN (missing), got ±inf")
    return estimate, truth


def _summarise(error: np.ndarray) -> TrajectoryErrors:
    """Error per sample (N,), NaN where the estimate is missing."""
    missing = np.isnan(error)
    used = np.abs(error[~missing])
    if used.size == 0:
        raise InvalidArgument(f"nothing to compare: all {error.size} estimates are missing")
    return TrajectoryErrors(
        mae=float(np.mean(used)), max_error=float(np.max(used)),
        rmse=float(np.sqrt(np.mean(used ** 2))), samples=int(used.size),
        missing=int(np.count_nonzero(missing)),
    )
