"""The ``feedback`` extension of the ingest socket (``docs/extensions/kit-feedback.md``):
for a kit that announced ``feedback/1`` in its hello, the server sends, from the live
estimates it computes anyway, the current exercise's angle, its target band and the
repetitions counted so far, at most ``FEEDBACK_HZ`` times a second. Display only: what is
stored and reported comes from the stored samples, as for any kit.

A repetition is counted when the exercise's angle, having been in the lower part of its
band (below ``LOW``, or at the exercise's start), rises into the upper part (above
``HIGH``): fractions of the band from its ``min_deg`` to its ``max_deg``, so a patient who
stops short of the top still gets their repetitions counted past two thirds of the way.
It is counted on the live estimates: each pose carries a ``trace`` of the estimates since
the previous pose (one per 0.05 s of stream time, ``live/estimator.py``), so a backlog a
kit sends at once after a lost link is counted like a stream in real time.

A count runs from its exercise's mark (``count_from``: the mark's time). A stream resumed
on the server that kept its live side (``endpoint``'s parked live state) goes on with the
same tracker, so the count goes on; one that lost it (the server restarted, the stream
went to another instance, a new stream in the session) starts a new count at its first
estimate (``count_from``: that estimate's time), which the kit adds to what it showed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: Extension name/version as a kit announces it in hello.
FEEDBACK_EXTENSION = "feedback/1"
#: Most feedback messages a second.
FEEDBACK_HZ = 10.0
#: Fractions of the band: below LOW arms a repetition, above HIGH counts it.
LOW, HIGH = 0.35, 0.65


@dataclass(frozen=True)
class Band:
    """An exercise's measuring angle and target band [deg]."""

    angle: str
    min_deg: float
    max_deg: float


class RepetitionCounter:
    """Counts rises from the lower third of a band into its upper third (hysteresis)."""

    def __init__(self, band: Band):
        span = band.max_deg - band.min_deg
        self.low = band.min_deg + LOW * span
        self.high = band.min_deg + HIGH * span
        self.count = 0
        self._armed = True  # an exercise starts from rest (its instruction says so)

    def update(self, value: float) -> int:
        if value <= self.low:
            self._armed = True
        elif value >= self.high and self._armed:
            self._armed = False
            self.count += 1
        return self.count


class FeedbackTracker:
    """One stream's feedback: the exercise marks as they come, the poses as they are
    estimated; ``pose`` gives the message to send (or None while rate-limited)."""

    def __init__(self, bands: Mapping[str, Band], measured: tuple[str, ...]):
        self.bands = dict(bands)
        self.measured = measured
        #: (t, label, stored) not yet passed by a pose
        self._marks: list[tuple[float, str, bool]] = []
        self._seen: set[tuple[float, str]] = set()  # a mark sent again after a resume
        self.exercise: str | None = None
        self.counter: RepetitionCounter | None = None
        #: stream time [s] the current count runs from (None: from the next estimate)
        self.count_from: float | None = None
        self._last_sent_t = -math.inf

    def mark(self, t: float, label: str, stored: bool = False) -> None:
        """A stream mark (stream time ``t`` [s]); it takes effect at the first pose at or
        after ``t``. ``stored``: read back from the session at a resume that lost the
        live state (its estimates before now are not counted: the count runs from the
        next estimate). A mark seen already is ignored."""
        if not (label.startswith("exercise:") or label.startswith("end:exercise:")):
            return
        if (t, label) in self._seen:
            return
        self._seen.add((t, label))
        self._marks.append((t, label, stored))

    def _pass_marks(self, t: float) -> None:
        while self._marks and self._marks[0][0] <= t:
            at, label, stored = self._marks.pop(0)
            if label.startswith("exercise:"):
                self.exercise = label.removeprefix("exercise:")
                band = self.bands.get(self.exercise)
                self.counter = RepetitionCounter(band) if band is not None else None
                self.count_from = None if stored else at
            elif self.exercise is not None and label == f"end:exercise:{self.exercise}":
                self.exercise, self.counter, self.count_from = None, None, None

    def pose(self, pose: Mapping[str, Any], now: float) -> dict[str, Any] | None:
        """The feedback message for a live ``pose`` update (``now``: monotonic [s]). The
        repetitions count on the pose's ``trace`` (the estimates since the last pose, a
        few per second of stream time: a backlog counts like a live stream), then on the
        pose itself."""
        trace = pose.get("trace") or {}
        times = trace.get("t") or []
        series = trace.get("angles_deg") or {}
        for i, ti in enumerate(times):  # at most 20 a second of stream time
            self._pass_marks(float(ti))
            band = self.bands.get(self.exercise) if self.exercise else None
            if self.counter is not None and band is not None and band.angle in series:
                value = series[band.angle][i]
                if value is not None and math.isfinite(value):
                    if self.count_from is None:
                        self.count_from = float(ti)
                    self.counter.update(value)
        t = float(pose["t"])
        self._pass_marks(t)
        angles = pose.get("angles_deg") or {}
        band = self.bands.get(self.exercise) if self.exercise else None
        value = angles.get(band.angle) if band is not None else None
        if self.counter is not None and value is not None and math.isfinite(value):
            if self.count_from is None:
                self.count_from = t
            self.counter.update(value)
        if now - self._last_sent_t < 1.0 / FEEDBACK_HZ:
            return None
        self._last_sent_t = now
        return {
            "type": "feedback", "t": t, "exercise": self.exercise,
            "angle": None if band is None else band.angle,
            "angle_deg": value if value is not None and math.isfinite(value) else None,
            "target": None if band is None else [band.min_deg, band.max_deg],
            "repetitions": 0 if self.counter is None else self.counter.count,
            "count_from": self.count_from if self.exercise is not None else None,
            "angles_deg": {k: v for k, v in angles.items() if k in self.measured
                           and v is not None and math.isfinite(v)},
            "warnings": list(pose.get("warnings") or ()),
        }
