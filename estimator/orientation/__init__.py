"""Orientation filters behind one interface (``base.OrientationFilter``), chosen by name."""

from ..errors import InvalidArgument
from .base import OrientationFilter, OrientationOutput
from .qcf import QcfParams, QuaternionComplementaryFilter

#: Filter name → class; each is built with its default parameters by ``make_filter``.
FILTERS: dict[str, type] = {"qcf": QuaternionComplementaryFilter}
DEFAULT_FILTER = "qcf"


def make_filter(name: str = DEFAULT_FILTER) -> OrientationFilter:
    """A fresh filter by name (``qcf``, ``ekf``, ``euler-cf``)."""
    if name not in FILTERS:
        raise InvalidArgument(f"unknown filter {name!r}; one of {', '.join(sorted(FILTERS))}")
    return FILTERS[name]()


__all__ = ["DEFAULT_FILTER", "FILTERS", "OrientationFilter", "OrientationOutput", "QcfParams",
           "QuaternionComplementaryFilter", "make_filter"]
