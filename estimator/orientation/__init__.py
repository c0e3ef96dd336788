"""Orientation filters behind one interface (``base.OrientationFilter``), chosen by name."""

from ..errors import InvalidArgument
from .base import OrientationFilter, OrientationOutput
from .ekf import EkfParams, ExtendedKalmanFilter
from .euler_cf import EulerCfParams, EulerComplementaryFilter
from .qcf import (
    GYRO_DELAY_MAX_S,
    LearntGyroBias,
    QcfParams,
    QuaternionComplementaryFilter,
    check_gyro_delay,
)

#: Filter name → class; each is built with its default parameters by ``make_filter``:
#: ``qcf`` the default, ``ekf`` the thesis's per-link EKF (plus gyroscope bias),
#: ``euler-cf`` the seed paper's complementary filter as published (a reference).
FILTERS: dict[str, type] = {"qcf": QuaternionComplementaryFilter,
                            "ekf": ExtendedKalmanFilter,
                            "euler-cf": EulerComplementaryFilter}
DEFAULT_FILTER = "qcf"


def make_filter(name: str = DEFAULT_FILTER, gyr_bias_prior=None,
                gyro_delay_s: float = 0.0, gyr_bias_prior_cov=None) -> OrientationFilter:
    """A fresh filter by name (``qcf``, ``ekf``, ``euler-cf``); ``gyr_bias_prior``: the
    gyroscope bias to start from [rad/s] (sensor frame), ``qcf`` only (None: zero), and
    ``gyr_bias_prior_cov`` its covariance [rad²/s²] (3 × 3; None: the filter's own);
    ``gyro_delay_s``: how far the kit's gyroscope lags its accelerometer [s], ``qcf`` only
    (0: in step)."""
    if name not in FILTERS:
        raise InvalidArgument(f"unknown filter {name!r}; one of {', '.join(sorted(FILTERS))}")
    delay = check_gyro_delay(gyro_delay_s)
    if delay and name not in GYRO_DELAY_FILTERS:
        raise InvalidArgument(f"filter {name!r} cannot take a gyroscope delay "
                              f"(gyro_delay_s); {', '.join(sorted(GYRO_DELAY_FILTERS))} can")
    extra = {"gyro_delay_s": delay} if delay else {}
    if gyr_bias_prior is None:
        if gyr_bias_prior_cov is not None:
            raise InvalidArgument("a gyroscope bias prior's covariance needs the prior "
                                  "(gyr_bias_prior)")
        return FILTERS[name](**extra)
    if name not in BIAS_PRIOR_FILTERS:
        raise InvalidArgument(f"filter {name!r} cannot start from a remembered gyroscope "
                              f"bias; {', '.join(sorted(BIAS_PRIOR_FILTERS))} can")
    if gyr_bias_prior_cov is not None:
        extra["gyr_bias_prior_cov"] = gyr_bias_prior_cov
    return FILTERS[name](gyr_bias_prior=gyr_bias_prior, **extra)


#: Filters that take a remembered gyroscope bias (``make_filter``'s ``gyr_bias_prior``) and
#: report their learnt one (``learnt_bias()``).
BIAS_PRIOR_FILTERS = frozenset({"qcf"})
#: Filters that take a kit's gyroscope delay (``make_filter``'s ``gyro_delay_s``).
GYRO_DELAY_FILTERS = frozenset({"qcf"})


__all__ = [
    "BIAS_PRIOR_FILTERS",
    "DEFAULT_FILTER",
    "FILTERS",
    "GYRO_DELAY_FILTERS",
    "GYRO_DELAY_MAX_S",
    "EkfParams",
    "EulerCfParams",
    "EulerComplementaryFilter",
    "ExtendedKalmanFilter",
    "LearntGyroBias",
    "OrientationFilter",
    "OrientationOutput",
    "QcfParams",
    "QuaternionComplementaryFilter",
    "check_gyro_delay",
    "make_filter",
]
