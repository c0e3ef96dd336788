"""The current exercise and its repetitions while a patient streams, for the dashboard's
live page (``GET /api/patients/{id}/live`` → ``exercise``).

A ``MotionWatch`` per watched patient listens to the live hub's poses (only while a page
polls that patient: it stops ``IDLE_S`` after the last poll) and keeps the session's
angles of the last ``BUFFER_S`` seconds. On a poll the repetitions are counted on a
worker thread with the report's own rules (``estimator.metrics.detect_repetitions`` and
``count_repetitions``;
without an exercise mark, the report's grouping of detected movements), so the count on
the live page is the count the report will give:

* an exercise mark open (``exercise:<name>``): its repetitions since the mark, of the
  catalogue's angle for it (``programs/catalogue.py``: ``pronation`` on
  ``forearm_pronation``, ``shoulder_flexion`` on ``shoulder_elevation``, as the kit's
  feedback counts it), else of the angle it names, else of its leading angle;
* no mark: the latest detected movement (``reports.content.detected_groups``) still
  going on (its last repetition less than ``GROUP_GAP_S`` ago), named as the report
  names it.

``repetitions_done`` is that count less a both-ways repetition whose turn the other way
is still to come (``_done``): the count the page shows.

Angles [deg] as the poses carry them; times are the session's [s].
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections import deque
from typing import Any

import numpy as np
from armtrack.estimator.arm.joints import REPORTED_ANGLES
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.metrics import BOTH_WAYS, count_repetitions, detect_repetitions
from armtrack.estimator.metrics.elbow_pivot import split_elbow_repetitions

from ..programs.catalogue import exercise as catalogue_exercise
from ..reports.words import exercise_words as words

#: Seconds of poses kept per watched patient.
BUFFER_S = 600.0
#: A watch stops this long after the last poll [s].
IDLE_S = 30.0
#: Angles that name a movement (the shoulder's elevation only when nothing else moved).
NAMING = tuple(a for a in REPORTED_ANGLES if not a.startswith("clavicle"))


class MotionWatch:
    """The poses of one patient's live session, fed from the hub."""

    def __init__(self, hub: Any, patient_id: int):
        self.hub = hub
        self.patient_id = patient_id
        self.session_id: int | None = None
        self.calibrated_from: float | None = None
        self._t: deque[float] = deque()
        self._angles: deque[np.ndarray] = deque()
        #: a forearm-only kit's turn terms per kept estimate (pull, ω⊥²; NaN: none)
        self._turns: deque[np.ndarray] = deque()
        self._lock = threading.RLock()  # series_and_turns reads series under it
        self.last_poll = time.monotonic()
        self.task: asyncio.Task | None = None

    def add(self, update: Any) -> None:
        """One hub update (on the event loop: appends only). A pose's ``trail`` (every
        estimate since the previous pose, ``server/live/estimator.py``) is what is kept;
        a pose without one (from an older server) gives its own angles."""
        if update.get("kind") != "pose":
            return
        session_id = update.get("session_id")
        t_pose = float(update["t"])
        trail = update.get("trail")
        if trail and trail.get("t"):
            times = np.asarray(trail["t"], dtype=float)
            rows = np.array(trail["angles_deg"], dtype=float)  # null → NaN
        else:
            angles = update.get("angles_deg") or {}
            times = np.array([t_pose])
            rows = np.array([[np.nan if angles.get(k) is None else float(angles[k])
                              for k in REPORTED_ANGLES]])
        if rows.ndim != 2 or rows.shape != (len(times), len(REPORTED_ANGLES)):
            return
        turn = (trail or {}).get("forearm_turn")
        turns = (np.array(turn, dtype=float) if turn and len(turn) == len(times)
                 else np.full((len(times), 2), np.nan))
        with self._lock:
            if session_id != self.session_id:
                self.session_id, self.calibrated_from = session_id, None
                self._t.clear()
                self._angles.clear()
                self._turns.clear()
            newer = times > (self._t[-1] if self._t else -np.inf)
            if not newer.any():
                return
            if self.calibrated_from is None and update.get("rom_deg"):
                self.calibrated_from = t_pose  # the running range starts after the poses
            self._t.extend(times[newer].tolist())
            self._angles.extend(rows[newer])
            self._turns.extend(turns[newer])
            while self._t and self._t[0] < t_pose - BUFFER_S:
                self._t.popleft()
                self._angles.popleft()
                self._turns.popleft()

    def series(self) -> tuple[int | None, float | None, np.ndarray, np.ndarray]:
        """A copy: session id, calibrated-from time, t (N,) [s], angles (N, A) [deg]."""
        with self._lock:
            t = np.fromiter(self._t, float, len(self._t))
            angles = (np.vstack(self._angles) if self._angles
                      else np.empty((0, len(REPORTED_ANGLES))))
            return self.session_id, self.calibrated_from, t, angles

    def series_and_turns(self) -> tuple[int | None, float | None, np.ndarray, np.ndarray,
                                        np.ndarray]:
        """``series`` and, read with it, the kept estimates' forearm turn terms (N, 2),
        NaN where none."""
        with self._lock:
            turns = np.vstack(self._turns) if self._turns else np.empty((0, 2))
            return (*self.series(), turns)

    async def run(self) -> None:
        with self.hub.subscribe(self.patient_id) as subscription:
            latest = self.hub.latest.get(self.patient_id)
            if latest is not None:
                self.add(latest)
            while time.monotonic() - self.last_poll < IDLE_S:
                with contextlib.suppress(TimeoutError):
                    update = await asyncio.wait_for(subscription.get(), IDLE_S)
                    if update is None:
                        return
                    self.add(update)


_watches: dict[tuple[int, int], MotionWatch] = {}


def watch(hub: Any, patient_id: int) -> MotionWatch:
    """The patient's watch (started on first use, kept alive by each call); call on the
    event loop."""
    key = (id(hub), patient_id)
    current = _watches.get(key)
    if current is None or current.task is None or current.task.done():
        current = MotionWatch(hub, patient_id)
        current.task = asyncio.get_running_loop().create_task(current.run())
        _watches[key] = current
        for old_key, old in list(_watches.items()):  # forget the stopped ones
            if old.task is not None and old.task.done():
                del _watches[old_key]
    current.last_poll = time.monotonic()
    return current


def watching(hub: Any, patient_id: int) -> MotionWatch | None:
    """The patient's running watch, kept alive; None when there is none."""
    current = _watches.get((id(hub), patient_id))
    if current is None or current.task is None or current.task.done():
        return None
    current.last_poll = time.monotonic()
    return current


def current_exercise(motion: MotionWatch, session_id: int, mark: dict[str, Any] | None,
                     lengths: SegmentLengths) -> dict[str, Any] | None:
    """The exercise going on and its repetitions so far (worker thread). ``mark``: the
    open exercise mark ``{"name", "t"}`` or None; ``lengths``: the session's body (a
    forearm-only kit's elbow is told from its shoulder by them, ``_elbows``). None before
    any pose after the calibration, or when nothing is going on. ``counted_to_s``: the
    stream time [s] the count has reached (the live estimates lag the stored stream when
    the server is busy; null before the first angle after the mark)."""
    from ..reports.content import GROUP_GAP_S, detected_groups, detected_name

    sid, calibrated_from, t, angles, turns = motion.series_and_turns()
    start = (mark["t"] if mark else calibrated_from if calibrated_from is not None
             else t[0] if len(t) else None)
    if sid != session_id or not len(t) or start >= t[-1]:
        # no angles yet after the mark: the live estimation has not caught up with it
        return ({"name": mark["name"], "label": words(mark["name"]), "source": "marks",
                 "since_s": mark["t"], "repetitions": 0, "repetitions_done": 0,
                 "angle": None,
                 "counted_to_s": None}
                if mark else None)
    rad = np.deg2rad(angles)
    index = {a: i for i, a in enumerate(REPORTED_ANGLES)}
    counted_to = float(t[-1])
    include = [(start, counted_to + 1e-6)]
    found = {}
    for angle in NAMING:
        column = rad[:, index[angle]]
        if not np.isfinite(column).any():
            continue
        found[angle] = detect_repetitions(column, t, include=include)
    if found.get("elbow_flexion"):  # a forearm-only kit's raise about the shoulder: not
        found["elbow_flexion"] = _elbows(found["elbow_flexion"], t, turns, lengths)
    if mark:
        entry = catalogue_exercise(mark["name"])
        angle = (entry.angle if entry is not None and entry.angle in found
                 else mark["name"] if mark["name"] in found else _leading(found))
        return {"name": mark["name"], "label": words(mark["name"]), "source": "marks",
                "since_s": mark["t"], "angle": angle, "counted_to_s": counted_to,
                "repetitions": _count(found, angle), "repetitions_done": _done(found, angle)}
    groups = detected_groups({k: v for k, v in found.items() if v})
    if not groups:
        return None
    a, b = groups[-1]
    if counted_to - b > GROUP_GAP_S:  # by the angles' clock: a lag is not a pause
        return None  # the last movement is over
    in_group = {k: [r for r in v if a <= r.start_s and r.end_s <= b]
                for k, v in found.items()}
    moved = [k for k in REPORTED_ANGLES if in_group.get(k)]
    name = detected_name(moved)
    angle = _leading({k: in_group[k] for k in moved})
    return {"name": name, "label": words(name), "source": "detected", "since_s": a,
            "angle": angle, "counted_to_s": counted_to,
            "repetitions": _count(in_group, angle), "repetitions_done": _done(in_group, angle)}


def _elbows(reps: Any, t: np.ndarray, turns: np.ndarray, lengths: SegmentLengths) -> tuple:
    """The elbow flexion's repetitions ``reps`` less those a forearm-only kit's forearm
    turned about the shoulder (the straight arm raised; ``split_elbow_repetitions``, the
    report's and the phone's rule, for the body of segment ``lengths``); all of them when
    the trail carried no turn terms."""
    if len(turns) != len(t) or not np.isfinite(turns).any():
        return reps
    return tuple(split_elbow_repetitions(reps, t, turns[:, 0], turns[:, 1], lengths)[0])


def _count(found: dict[str, Any], angle: str | None) -> int:
    """``angle``'s repetitions among its excursions ``found[angle]`` (the report's count)."""
    return count_repetitions(found.get(angle, ()), angle in BOTH_WAYS) if angle else 0


def _done(found: dict[str, Any], angle: str | None) -> int:
    """``angle``'s repetitions done so far (``repetitions_done``): the report's count
    (``_count``) less a both-ways repetition that has made only its first turn. The
    report counts such a repetition (its count is the larger side's turns: a session
    that ends there has it), so the live count, which goes up with the first turn, was a
    repetition ahead of the patient through every second turn. A repetition is under way
    when the newest turn raised the count and follows a turn the other way (or none):
    the patient alternates, and the turn back is still to come. After a turn to the same
    side (a patient who rests at one end, or turns one side ×N then the other ×N) each
    turn is a repetition of its own, as the report counts it, and none is under way."""
    turns = tuple(found.get(angle, ())) if angle else ()
    count = _count(found, angle)
    if angle not in BOTH_WAYS or not turns:
        return count
    last, before = turns[-1], turns[:-1]
    if (count_repetitions(before, True) < count
            and (not before or before[-1].direction != last.direction)):
        return count - 1
    return count


def _leading(found: dict[str, Any]) -> str | None:
    """The angle with the largest total amplitude (the shoulder's elevation only when
    nothing else repeated)."""
    scored = {k: sum(abs(r.amplitude) for r in v) for k, v in found.items() if v}
    others = {k: v for k, v in scored.items() if k != "shoulder_elevation"}
    chosen = others or scored
    return max(chosen, key=chosen.get) if chosen else None
