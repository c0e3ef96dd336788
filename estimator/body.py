"""The body: sides, sensor places and segment lengths (``docs/spec/kinematics.md``).

Lengths are in metres. Without measured lengths, they follow body height ``h`` as in the
seed paper (Tsilomitrou et al. 2021): ``l_c = 0.129 h``, ``l_u = 0.186 h``,
``l_f = 0.146 h``, ``l_h = 0.108 h``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from .errors import InvalidArgument

Side = Literal["right", "left"]
SIDES: tuple[Side, ...] = ("right", "left")

#: Sensor places, proximal to distal; also the names of the segments they sit on.
SENSOR_NAMES: tuple[str, ...] = ("trunk", "clavicle", "upper_arm", "forearm", "hand")

#: Fractions of body height (seed paper, section 2.3).
HEIGHT_FRACTIONS = {"clavicle": 0.129, "upper_arm": 0.186, "forearm": 0.146, "hand": 0.108}

#: Plausible body heights [m]; outside them a height is refused as a typo.
HEIGHT_RANGE_M = (0.5, 2.6)


@dataclass(frozen=True)
class SegmentLengths:
    """Segment lengths [m]: sternal notch to shoulder centre, shoulder to elbow,
    elbow to wrist, wrist to hand tip."""

    clavicle: float
    upper_arm: float
    forearm: float
    hand: float

    def __post_init__(self) -> None:
        for name in HEIGHT_FRACTIONS:
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 < value < 1.5):
                raise InvalidArgument(
                    f"segment length {name} must be a finite length in (0, 1.5) m, got {value!r}"
                )

    @classmethod
    def from_height(cls, height_m: float) -> SegmentLengths:
        """Lengths from body height [m] with the seed paper's fractions."""
        lo, hi = HEIGHT_RANGE_M
        if not (math.isfinite(height_m) and lo <= height_m <= hi):
            raise InvalidArgument(f"body height must be within {lo}–{hi} m, got {height_m!r}")
        return cls(**{name: f * height_m for name, f in HEIGHT_FRACTIONS.items()})

    def as_dict(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in HEIGHT_FRACTIONS}
