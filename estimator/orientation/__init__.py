"""Orientation filters behind one interface (``base.OrientationFilter``), chosen by name."""

from ..errors import InvalidArgument
from .base import OrientationFilter, OrientationOutput
from .ekf import EkfParams, ExtendedKalmanFilter
from .euler_cf import EulerCfParams, EulerComplementaryFilter
from .qcf import QcfParams, QuaternionComplementaryFilter

#: Filter name → class; each is built with its default parameters by ``make_filter``:
#: ``qcf`` the default, ``ekf`` the thesis's per-link EKF (plus gyroscope bias),
#: ``euler-cf`` the seed paper's complementary filter as published (a reference).
FILTERS: dict[str, type] = {"qcf": QuaternionComplementaryFilter,
                            "ekf": ExtendedKalmanFilter,
                            "euler-cf": EulerComplementaryFilter}
DEFAULT_FILTER = "qcf"


def make_filter(name: str = DEFAULT_FILTER) -> OrientationFilter:
    """A fresh filter by name (``qcf``, ``ekf``, ``euler-cf``)."""
    if name not in FILTERS:
        raise InvalidArgument(f"unknown filter {name!r}; one of {', '.join(sorted(FILTERS))}")
    return FILTERS[name]()


__all__ = ["DEFAULT_FILTER", "FILTERS", "EkfParams", "EulerCfParams", "EulerComplementaryFilter",
           "ExtendedKalmanFilter", "OrientationFilter", "OrientationOutput", "QcfParams",
           "QuaternionComplementaryFilter", "make_filter"]
