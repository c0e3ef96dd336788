"""The ``feedback`` extension of the ingest socket (``docs/extensions/kit-feedback.md``):
for a kit that announced ``feedback/1`` in its hello, the server sends, from the live
estimates it computes anyway, the current exercise's angle, its target band and the
repetitions counted so far, at most ``FEEDBACK_HZ`` times a second. Display only: what is
stored and reported comes from the stored samples, as for any kit.

Repetitions are counted by the report's own rule (``estimator.metrics.count_repetitions``
on ``detect_repetitions``' excursions: a full cycle out and back counted once — the elbow
bent and straightened is one; the palm turned down and up is one, the count going up with
the first turn of each), on the catalogue's angle for the exercise (``Band.angle``),
causally: an excursion counts once it is back at rest. So the kit shows the count the
report and the therapist's live page (``server/live/motion.py``) give. The target band is
shown, not used for counting (the report counts an excursion short of the target too).
It is counted on the live estimates: each pose carries the ``trail`` of the estimates
since the previous pose (25 per second of stream time, ``live/estimator.py``;
docs/extensions/live-exercise.md), so a backlog a kit sends at once after a lost link is
counted like a stream in real time.

A count runs from its exercise's mark (``count_from``: the mark's time). A stream resumed
on the server that kept its live side (``endpoint``'s parked live state) goes on with the
same tracker, so the count goes on; one that lost it (the server restarted, the stream
went to another instance, a new stream in the session) starts a new count at its first
estimate (``count_from``: that estimate's time), which the kit adds to what it showed.

The counting is CPU work (a recount is ~2 ms on two minutes of angle): a stream's
``FeedbackRunner`` does it on the server's CPU thread pool, never on the event loop, one
job at a time per stream; what comes while a job runs waits for the next, which counts it
all and answers for the newest pose only.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from armtrack.estimator.arm.joints import REPORTED_ANGLES
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.metrics import BOTH_WAYS, Repetition, count_repetitions, detect_repetitions
from armtrack.estimator.metrics.elbow_pivot import split_elbow_repetitions

log = logging.getLogger("armtrack.ingest")

#: Extension name/version as a kit announces it in hello.
FEEDBACK_EXTENSION = "feedback/1"
#: Most feedback messages a second.
FEEDBACK_HZ = 10.0
#: Stream seconds of a count's angle kept for recounting: once twice this is kept, the
#: samples before a repetition that ended longer ago than this are let go, their count
#: kept [s].
KEEP_S = 60.0


@dataclass(frozen=True)
class Band:
    """An exercise's measuring angle and target band [deg]."""

    angle: str
    min_deg: float
    max_deg: float


class RepetitionCounter:
    """The report's repetition rule on one exercise's angle since its count began.

    ``add`` appends estimates; ``recount`` applies ``detect_repetitions`` to those of the
    last ``KEEP_S`` seconds or so (older ones, before an excursion already counted, are
    let go, the excursions found in them kept) and counts the excursions by
    ``count_repetitions``. A repetition counts once its return to rest is seen; the
    count shown never goes back (a later sample may move the rest level a little)."""

    def __init__(self, band: Band, lengths: SegmentLengths):
        self.band = band
        #: the session's body: where its elbow and shoulder lie from the phone
        self.lengths = lengths
        self.count = 0
        #: on a both-ways angle, the turns the side that leads is ahead by (0: each turn
        #: has its turn the other way; the count is complete), else 0
        self.unpaired = 0
        #: movements of the elbow's angle the forearm made about the shoulder (the arm
        #: raised straight, ``elbow_pivot``): not counted (a forearm-only kit's elbow)
        self.not_elbow = 0
        self._not_elbow_committed = 0
        self._t: list[float] = []
        self._deg: list[float] = []
        self._turn: list[tuple[float, float]] = []  # (pull, ω⊥²) per sample, NaN: none
        self._committed: list[Repetition] = []  # excursions of samples already let go
        self._stale = False

    def add(self, t: np.ndarray, deg: np.ndarray, turn: np.ndarray | None = None) -> None:
        """Estimates at stream times ``t`` [s] (n,), the angle [deg] (n,) (NaN: none),
        a forearm-only kit's turn terms ``turn`` (n, 2) or None; times not after the
        last one kept are ignored."""
        keep = np.isfinite(deg) & np.isfinite(t)
        if self._t:
            keep &= t > self._t[-1]
        if keep.any():
            self._t.extend(t[keep].tolist())
            self._deg.extend(deg[keep].tolist())
            terms = (np.asarray(turn, dtype=float)[keep] if turn is not None
                     else np.full((int(keep.sum()), 2), np.nan))
            self._turn.extend(map(tuple, terms.tolist()))
            self._stale = True

    def _split(self, t: np.ndarray, reps: tuple[Repetition, ...]
               ) -> tuple[list[Repetition], list[Repetition]]:
        """The elbow's repetitions and those the forearm turned about the shoulder
        (``elbow_pivot.split_elbow_repetitions``: the report's rule, for the session's
        body); every one the elbow's on another angle or without turn terms."""
        if self.band.angle != "elbow_flexion" or not reps:
            return list(reps), []
        turn = np.asarray(self._turn, dtype=float)
        kept, refused = split_elbow_repetitions(reps, t, turn[:, 0], turn[:, 1], self.lengths)
        return kept, [rep for rep, _ in refused]

    def recount(self) -> int:
        """The repetitions so far (the report's rule on the samples kept)."""
        if not self._stale:
            return self.count
        self._stale = False
        t = np.asarray(self._t)
        reps = detect_repetitions(np.deg2rad(np.asarray(self._deg)), t)
        kept, refused = self._split(t, reps)
        turns = (*self._committed, *kept)
        both_ways = self.band.angle in BOTH_WAYS
        self.count = max(self.count, count_repetitions(turns, both_ways))
        self.unpaired = (abs(sum(r.direction for r in turns)) if both_ways else 0)
        self.not_elbow = max(self.not_elbow, self._not_elbow_committed + len(refused))
        if t[-1] - t[0] < 2 * KEEP_S:
            return self.count
        done = [r for r in reps if r.end_s < t[-1] - KEEP_S]
        if done:  # let go of the samples before the last repetition long done: cut in
            # the rest between it and the next (so that the next starts from rest)
            after = reps[len(done)].start_s if len(reps) > len(done) else t[-1] - KEEP_S
            cut = int(np.searchsorted(t, 0.5 * (done[-1].end_s + after)))
            self._committed.extend(r for r in done if r not in refused)
            self._not_elbow_committed += sum(r in refused for r in done)
            del self._t[:cut], self._deg[:cut], self._turn[:cut]
        return self.count


class FeedbackTracker:
    """One stream's feedback: the exercise marks as they come, the poses as they are
    estimated; ``pose`` gives the message to send (or None while rate-limited)."""

    def __init__(self, bands: Mapping[str, Band], measured: tuple[str, ...],
                 lengths: SegmentLengths):
        self.bands = dict(bands)
        self.measured = measured
        #: the session's body (its elbow's and shoulder's distances from a forearm phone)
        self.lengths = lengths
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
                self.counter = (RepetitionCounter(band, self.lengths) if band is not None
                                else None)
                self.count_from = None if stored else at
            elif self.exercise is not None and label == f"end:exercise:{self.exercise}":
                self.exercise, self.counter, self.count_from = None, None, None

    def _count(self, times: np.ndarray, series: Mapping[str, Any], a: int, b: int,
               turn: np.ndarray | None = None) -> None:
        """Give the current count the estimates ``a:b`` of ``series`` at ``times`` (and
        of a forearm-only kit's turn terms ``turn``, (n, 2), or None)."""
        band = self.bands.get(self.exercise) if self.exercise else None
        if self.counter is None or band is None or band.angle not in series:
            return
        deg = np.asarray(series[band.angle][a:b], dtype=float)
        finite = np.flatnonzero(np.isfinite(deg))
        if not finite.size:
            return
        if self.count_from is None:
            self.count_from = float(times[finite[0]])
        self.counter.add(times, deg, None if turn is None else turn[a:b])

    def apply(self, events: list[tuple], now: float) -> dict[str, Any] | None:
        """Queued ``("mark", t, label, stored)`` and ``("pose", pose)`` events in the order
        they came (``FeedbackRunner``): every pose's trail counts; the message (or None) is
        the newest pose's (``now``: monotonic [s])."""
        last = None
        for event in events:
            if event[0] == "mark":
                self.mark(*event[1:])
            else:
                last = event[1]
                self._take(last)
        return None if last is None else self._message(last, now)

    def pose(self, pose: Mapping[str, Any], now: float) -> dict[str, Any] | None:
        """The feedback message for a live ``pose`` update (``now``: monotonic [s]). The
        repetitions count on the pose's ``trail`` (the estimates since the last pose, 25
        per second of stream time: a backlog counts like a live stream), then on the
        pose itself."""
        self._take(pose)
        return self._message(pose, now)

    def _take(self, pose: Mapping[str, Any]) -> None:
        """Count a pose's trail, then the pose itself, passing the marks on the way."""
        trail = pose.get("trail") or {}
        times = np.asarray(trail.get("t") or [], dtype=float)
        rows = trail.get("angles_deg") or []  # in REPORTED_ANGLES order (live-exercise.md)
        table = np.array(rows, dtype=float).reshape(-1, len(REPORTED_ANGLES))  # null: NaN
        series = ({name: table[:, i] for i, name in enumerate(REPORTED_ANGLES)}
                  if rows else {})
        turn_rows = trail.get("forearm_turn")  # a forearm-only kit's (live/estimator.py)
        turn = (np.array(turn_rows, dtype=float).reshape(-1, 2)
                if rows and turn_rows and len(turn_rows) == len(rows) else None)
        t = float(pose["t"])
        angles = pose.get("angles_deg") or {}
        # the trail, then the pose itself (when it is newer), cut at the marks they pass
        if not times.size or t > times[-1]:
            if turn is not None:
                turn = np.vstack([turn, [[np.nan, np.nan]]])
            times = np.append(times, t)
            series = {k: np.append(series[k] if k in series else np.full(times.size - 1,
                                                                         np.nan),
                                   np.nan if angles.get(k) is None else angles[k])
                      for k in set(series) | set(angles)}
        first = 0
        while first < times.size:
            upto = (int(np.searchsorted(times, self._marks[0][0], side="left"))
                    if self._marks else times.size)
            if upto <= first:  # the next mark takes effect at this estimate
                self._pass_marks(float(times[first]))
                upto = (int(np.searchsorted(times, self._marks[0][0], side="left"))
                        if self._marks else times.size)
                upto = max(upto, first + 1)
            self._count(times[first:upto], series, first, upto, turn)
            first = upto
        self._pass_marks(t)

    def _message(self, pose: Mapping[str, Any], now: float) -> dict[str, Any] | None:
        """The message for ``pose`` once counted (None while rate-limited)."""
        t = float(pose["t"])
        angles = pose.get("angles_deg") or {}
        band = self.bands.get(self.exercise) if self.exercise else None
        value = angles.get(band.angle) if band is not None else None
        if now - self._last_sent_t < 1.0 / FEEDBACK_HZ:
            return None
        self._last_sent_t = now
        return {
            "type": "feedback", "t": t, "exercise": self.exercise,
            "angle": None if band is None else band.angle,
            "angle_deg": value if value is not None and math.isfinite(value) else None,
            "target": None if band is None else [band.min_deg, band.max_deg],
            "repetitions": 0 if self.counter is None else self.counter.recount(),
            "unpaired_turns": 0 if self.counter is None else self.counter.unpaired,
            "not_elbow_movements": 0 if self.counter is None else self.counter.not_elbow,
            "count_from": self.count_from if self.exercise is not None else None,
            "angles_deg": {k: v for k, v in angles.items() if k in self.measured
                           and v is not None and math.isfinite(v)},
            "warnings": list(pose.get("warnings") or ()),
        }


class FeedbackRunner:
    """One stream's ``FeedbackTracker``, run off the event loop. On the loop, ``mark`` and
    ``pose`` only queue; one job at a time (per stream) applies the queue in order on
    ``run`` (a thread pool's caller) and sends the newest pose's message with ``send``.
    So at most one recount per stream is under way, a stale pose's message is never
    computed, and messages go out in order. Parked with the stream's live side; a resumed
    connection sets ``send`` to its own."""

    def __init__(self, tracker: FeedbackTracker,
                 run: Callable[..., Awaitable[Any]],
                 send: Callable[[dict[str, Any]], Awaitable[None]]):
        self.tracker = tracker
        self.send = send
        self._run = run
        self._queue: list[tuple] = []
        self._job: asyncio.Task | None = None

    def mark(self, t: float, label: str, stored: bool = False) -> None:
        """As ``FeedbackTracker.mark``, applied before the next pose."""
        self._queue.append(("mark", t, label, stored))

    def pose(self, pose: Mapping[str, Any]) -> None:
        """A published live pose (on the event loop): counted, its message sent if due."""
        self._queue.append(("pose", pose))
        if self._job is None or self._job.done():
            self._job = asyncio.get_running_loop().create_task(self._work())

    async def _work(self) -> None:
        while any(event[0] == "pose" for event in self._queue):
            events, self._queue = self._queue, []
            try:
                message = await self._run(self._apply, events)
            except Exception:  # a fault of the count is the kit's display only: logged
                log.exception("kit feedback failed")
                continue
            if message is not None:
                await self.send(message)

    def _apply(self, events: list[tuple]) -> dict[str, Any] | None:
        return self.tracker.apply(events, time.monotonic())
