"""Range of motion per angle against normal values, for reports (``docs/spec/api.md``).

Input angles in [rad]; every figure out is in **degrees**, named ``_deg``: a range of
motion is a clinical number compared with normal values printed in degrees
(``NORMAL_RANGE_DEG``, AAOS; ``PAPER_RANGE_DEG``, the seed paper's Table 2), and the
report's ``rom`` object is in degrees.

* Samples: inside ``include`` windows (all when not given; an exercise's marks), outside
  ``exclude`` windows (the calibration poses are not exercise), finite (NaN = no
  estimate).
* **Robust extremes.** ``min`` and ``max`` are percentiles, ``P(q)`` and ``P(100 − q)``,
  so that a short spike (a magnetic disturbance, a glitch) does not make the range. By
  default ``q`` is chosen so that each tail holds ``spike_s`` = 0.1 s of samples:
  ``q = 100 · spike_s / (n · dt)`` with ``dt`` the median sample interval, so a spike of
  up to 0.1 s is ignored at any recording length, while a peak visited only briefly (one
  repetition in a long session) loses at most 0.05 s on each side of it — 0.1% of the
  amplitude of a 5-s repetition. A fixed percentile (``percentile=0.5``
  for ``P0.5 … P99.5``) cuts a fixed *fraction* instead: 1.5 s of a 5-minute session,
  which costs a fifth of the amplitude of a single 5-second repetition. ``percentile=0``
  gives the exact min and max. The extremes are those of the samples as given: noise on
  them widens the range by about its own peak values (smooth the angles first if noisy).
* ``range = max − min``. ``percent_of_normal`` (``docs/spec/api.md``): how far the session
  reached in the direction it moved most, as a share of the normal range on that side of
  zero, ``max(max ÷ normal_max, min ÷ normal_min) × 100``, a term only for a side the
  normal range has (``normal_max > 0``, ``normal_min < 0``), clamped at 0 (shoulder
  flexion to 150° of AAOS −60…180° → 83 %, not the 63 % of the whole span). Against AAOS;
  ``percent_of_paper`` the same against the paper's Table 2, and a target's percentage
  (server reports) the same against the target. Angles without a normal range (the
  clavicle's) have ``None`` there.
* **Moved**: an angle moved when its (robust) range is at least ``moved_threshold``,
  10° by default: above the noise, drift and crosstalk of a good estimate on an idle joint
  (the shared recordings' peer build: worst-angle RMSE up to 1.4°, so ±3σ ≈ 8°), below
  the smallest exercise of interest. Reports list only the angles that moved.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from ..arm.joints import NORMAL_RANGE_DEG, PAPER_RANGE_DEG, REPORTED_ANGLES
from ..errors import InvalidArgument
from ..sampling import sample_interval_s
from .timebase import Windows, as_series, select


@dataclass(frozen=True)
class RomParams:
    """Parameters of the range of motion (module docstring)."""

    #: Tail percentile [%]: ``min = P(percentile)``, ``max = P(100 − percentile)``; ``0``:
    #: the exact extremes; ``None``: from ``spike_s``.
    percentile: float | None = None
    #: With ``percentile=None``, each tail holds this much time of samples [s].
    spike_s: float = 0.1
    #: An angle whose range is at least this moved [rad].
    moved_threshold: float = np.deg2rad(10.0)

    def __post_init__(self) -> None:
        if self.percentile is not None and not 0.0 <= self.percentile < 50.0:
            raise InvalidArgument(f"percentile must be in [0, 50) %, got {self.percentile!r}")
        if not self.spike_s >= 0.0:
            raise InvalidArgument(f"spike_s must be ≥ 0 s, got {self.spike_s!r}")
        if not self.moved_threshold >= 0.0:
            raise InvalidArgument(
                f"moved_threshold must be ≥ 0 rad, got {self.moved_threshold!r}")


@dataclass(frozen=True)
class RangeOfMotion:
    """One angle's range of motion. All angles in [deg]; percentages in [%]."""

    angle: str
    min_deg: float
    max_deg: float
    range_deg: float
    #: AAOS normal range (``NORMAL_RANGE_DEG``); ``None`` when the angle has none.
    normal_min_deg: float | None
    normal_max_deg: float | None
    percent_of_normal: float | None
    #: The seed paper's Table 2 (``PAPER_RANGE_DEG``); ``None`` when it has none.
    paper_min_deg: float | None
    paper_max_deg: float | None
    percent_of_paper: float | None
    #: ``range ≥ moved_threshold``.
    moved: bool
    #: Samples used.
    samples: int
    #: The tail percentile used [%].
    percentile: float

    def to_report(self) -> dict[str, float | None]:
        """The report's ``rom`` entry (``docs/spec/api.md``), degrees."""
        return {"min": self.min_deg, "max": self.max_deg, "range": self.range_deg,
                "normal_min": self.normal_min_deg, "normal_max": self.normal_max_deg,
                "percent_of_normal": self.percent_of_normal}


def percent_of(min_deg: float, max_deg: float,
               reference: tuple[float, float] | None) -> float | None:
    """How far ``min_deg…max_deg`` reached on the side it went furthest, as a share of
    ``reference`` (low, high) [deg] on that side of zero [%]:
    ``max(max ÷ high, min ÷ low) × 100``, the first term only where ``high > 0``, the
    second only where ``low < 0``, clamped at 0 (``docs/spec/api.md``). ``None`` without a
    reference, or when it has no side away from zero."""
    if reference is None:
        return None
    low, high = reference
    shares = []
    if high > 0:
        shares.append(max_deg / high)
    if low < 0:
        shares.append(min_deg / low)
    if not shares:
        return None
    return float(max(0.0, *shares) * 100.0)


def range_of_motion(
    name: str,
    angle: np.ndarray,
    t: np.ndarray,
    *,
    include: Windows | None = None,
    exclude: Windows | None = None,
    params: RomParams | None = None,
) -> RangeOfMotion:
    """Range of motion of the angle ``name`` (one of ``REPORTED_ANGLES``).

    ``angle``: [rad], (N,), NaN where there is no estimate; ``t``: [s], (N,), increasing.
    ``include`` / ``exclude``: windows ``(start_s, end_s)`` [s] of samples to use / leave
    out. Raises InvalidArgument for an unknown name or when no sample is left.
    """
    p = params or RomParams()
    if name not in REPORTED_ANGLES:
        raise InvalidArgument(f"unknown angle {name!r}; expected one of {list(REPORTED_ANGLES)}")
    t, angle = as_series(t, angle)
    use = select(t, include, exclude) & np.isfinite(angle)
    n = int(np.count_nonzero(use))
    if n == 0:
        raise InvalidArgument(f"{name}: no finite sample inside the selected windows "
                              f"({angle.size} samples in all)")
    values = np.rad2deg(angle[use])
    if p.percentile is not None:
        q = p.percentile
    else:
        dt = sample_interval_s(t[use]) if n > 1 else 0.0
        q = min(100.0 * p.spike_s / (n * dt), 49.0) if dt > 0 else 0.0
    low, high = (float(v) for v in np.percentile(values, [q, 100.0 - q]))
    span = high - low
    normal = NORMAL_RANGE_DEG.get(name)
    paper = PAPER_RANGE_DEG.get(name)
    return RangeOfMotion(
        angle=name, min_deg=low, max_deg=high, range_deg=span,
        normal_min_deg=normal[0] if normal else None,
        normal_max_deg=normal[1] if normal else None,
        percent_of_normal=percent_of(low, high, normal),
        paper_min_deg=paper[0] if paper else None,
        paper_max_deg=paper[1] if paper else None,
        percent_of_paper=percent_of(low, high, paper),
        moved=bool(span >= np.rad2deg(p.moved_threshold)), samples=n, percentile=float(q),
    )


def range_of_motion_table(
    angles: Mapping[str, np.ndarray],
    t: np.ndarray,
    *,
    include: Windows | None = None,
    exclude: Windows | None = None,
    params: RomParams | None = None,
    moved_only: bool = True,
) -> dict[str, RangeOfMotion]:
    """``range_of_motion`` of each angle of ``angles`` (name → [rad] (N,)), in the order of
    ``REPORTED_ANGLES``; only the angles that moved unless ``moved_only=False``."""
    unknown = sorted(set(angles) - set(REPORTED_ANGLES))
    if unknown:
        raise InvalidArgument(f"unknown angle(s) {unknown}; expected {list(REPORTED_ANGLES)}")
    table = {name: range_of_motion(name, angles[name], t, include=include, exclude=exclude,
                                   params=params)
             for name in REPORTED_ANGLES if name in angles}
    return {k: v for k, v in table.items() if v.moved or not moved_only}


def rom_report(table: Mapping[str, RangeOfMotion]) -> dict[str, dict[str, float | None]]:
    """The report's ``rom`` object (``docs/spec/api.md``): angle name → entry, degrees."""
    return {name: rom.to_report() for name, rom in table.items()}


#: Seconds after the last calibration pose's end still left out of every metric: the arm
#: returns from the T-pose (the live view, ``armtrack estimate``, the reports and the
#: sessions list all use this rule).
CALIBRATION_TAIL_S = 2.5


def calibration_exclusion(t_first: float, pose_ends: Iterable[float]
                          ) -> list[tuple[float, float]]:
    """The window every metric leaves out as calibration, ``[(start, end)]`` [s]: from
    the first estimate ``t_first`` to ``CALIBRATION_TAIL_S`` after the last pose ends
    (whatever the patient did before the poses is setting up, not exercise); ``[]``
    without poses."""
    ends = [float(e) for e in pose_ends]
    return [(float(t_first), max(ends) + CALIBRATION_TAIL_S)] if ends else []
