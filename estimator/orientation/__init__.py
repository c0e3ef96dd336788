"""Orientation filters behind one interface (``base.OrientationFilter``), chosen by name."""

from ..errors import InvalidArgument
from .base import OrientationFilter, OrientationOutput
from .ekf import EkfParams, ExtendedKalmanFilter
from .euler_cf import EulerCfParams, EulerComplementaryFilter
from .qcf import LearntGyroBias, QcfParams, QuaternionComplementaryFilter

#: Filter name → class; each is built with its default parameters by ``make_filter``:
#: ``qcf`` the default, ``ekf`` the thesis's per-link EKF (plus gyroscope bias),
#: ``euler-cf`` the seed paper's complementary filter as published (a reference).
FILTERS: dict[str, type] = {"qcf": QuaternionComplementaryFilter,
                            "ekf": ExtendedKalmanFilter,
                            "euler-cf": EulerComplementaryFilter}
DEFAULT_FILTER = "qcf"


def make_filter(name: str = DEFAULT_FILTER, gyr_bias_prior=None) -> OrientationFilter:
    """A fresh filter by name (``qcf``, ``ekf``, ``euler-cf``); ``gyr_bias_prior``: the
    gyroscope bias to start from [rad/s] (sensor frame), ``qcf`` only (None: zero)."""
    if name not in FILTERS:
        raise InvalidArgument(f"unknown filter {name!r}; one of {', '.join(sorted(FILTERS))}")
    if gyr_bias_prior is None:
        return FILTERS[name]()
    if name not in BIAS_PRIOR_FILTERS:
        raise InvalidArgument(f"filter {name!r} cannot start from a remembered gyroscope "
                              f"bias; {', '.join(sorted(BIAS_PRIOR_FILTERS))} can")
    return FILTERS[name](gyr_bias_prior=gyr_bias_prior)


#: Filters that take a remembered gyroscope bias (``make_filter``'s ``gyr_bias_prior``) and
#: report their learnt one (``learnt_bias()``).
BIAS_PRIOR_FILTERS = frozenset({"qcf"})


__all__ = ["BIAS_PRIOR_FILTERS", "DEFAULT_FILTER", "FILTERS", "EkfParams", "EulerCfParams",
           "EulerComplementaryFilter", "ExtendedKalmanFilter", "LearntGyroBias",
           "OrientationFilter", "OrientationOutput", "QcfParams",
           "QuaternionComplementaryFilter", "make_filter"]
