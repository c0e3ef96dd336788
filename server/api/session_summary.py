"""Session summaries for the dashboard (read-only): the exercises (the marks; without
marks, those the report detected) with their repetitions once estimated, the duration, the range of
motion of the angles that moved against normal values (calibration poses left out), a
one-line ROM headline and the data quality (lost samples per sensor, calibration
warnings, a session too short to judge). Computed from the stored samples and estimates;
kept in memory per session until its data or estimates change."""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Annotated, Any

import numpy as np
from armtrack.estimator.arm.joints import REPORTED_ANGLES
from armtrack.estimator.errors import EstimatorError
from armtrack.estimator.metrics.rom import calibration_exclusion, range_of_motion_table
from fastapi import APIRouter, Query
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..builds import REPORTS
from ..db import models
from ..store.coverage import session_coverage
from ..store.processing import stored_estimates
from .deps import Db, Held, Therapist, long_list, own_patient, own_session
from .live_status import block_totals, lost_fraction
from .schemas import Id

router = APIRouter(prefix="/api", tags=["sessions"])

#: Lost-sample share above which the data quality is ``fair``, and ``poor``.
LOST_FAIR, LOST_POOR = 0.01, 0.05
#: A finished session shorter than this [s] is at best ``fair``: calibration poses
#: alone take ~10 s, so it was cut off before much exercise (a 13-s session is not
#: "good data").
SHORT_S = 30.0


class KeptSummaries:
    """Summaries of closed sessions, by session id, with the key they were made for: at
    most ``entries`` of them and ``parts`` exercises and calibration poses in all, the
    least recently kept going first. (Bounded by count alone, 2,000: a session keeps up
    to 1,000 marks, a summary then ~190 KB of 500 exercises, and 601 such summaries kept
    the server +121 MB for good, 2,000 ~400 MB; att18,
    tests/test_security_long_lists.py.) Thread-safe."""

    def __init__(self, entries: int, parts: int):
        self.entries, self.parts = entries, parts
        self._kept: OrderedDict[int, tuple[tuple, dict[str, Any], int]] = OrderedDict()
        self._parts = 0
        self._lock = threading.Lock()

    def get(self, session_id: int) -> tuple[tuple, dict[str, Any]] | None:
        with self._lock:
            found = self._kept.get(session_id)
        return None if found is None else (found[0], found[1])

    def put(self, session_id: int, key: tuple, summary: dict[str, Any]) -> None:
        weight = 1 + len(summary["exercises"]) + len(summary["calibration_poses"])
        with self._lock:
            if (old := self._kept.pop(session_id, None)) is not None:
                self._parts -= old[2]
            self._kept[session_id] = (key, summary, weight)
            self._parts += weight
            while self._kept and (len(self._kept) > self.entries or self._parts > self.parts):
                self._parts -= self._kept.popitem(last=False)[1][2]


#: Kept summaries: a usual session's has a few exercises, so ~2,000 of them (a few MB).
_cache = KeptSummaries(entries=2000, parts=50_000)


def _marks(db: DbSession, session_id: int) -> list[tuple[float, str]]:
    return [(float(t), label) for t, label in db.execute(
        select(models.Mark.t, models.Mark.label).where(models.Mark.session_id == session_id)
        .order_by(models.Mark.t, models.Mark.id)).all()]


def _periods(marks: list[tuple[float, str]], end_t: float | None
             ) -> tuple[list[dict[str, Any]], list[tuple[float, float]]]:
    """Exercises (name, start, end) and calibration pose windows from the marks."""
    exercises: list[dict[str, Any]] = []
    poses: list[tuple[float, float]] = []
    open_: dict[str, float] = {}
    for t, label in marks:
        if label.startswith("end:"):
            begun = label[4:]
            if begun in open_:
                start = open_.pop(begun)
                if begun.startswith("exercise:"):
                    exercises.append({"name": begun[9:], "start": start, "end": t})
                else:
                    poses.append((start, t))
        else:
            open_[label] = t
    for label, start in open_.items():  # still open (live, or the kit never ended it)
        if label.startswith("exercise:"):
            exercises.append({"name": label[9:], "start": start, "end": end_t, "ended": False})
        elif end_t is not None:
            poses.append((start, end_t))
    exercises.sort(key=lambda e: e["start"])
    return exercises, poses


def _asked_per_set(db: DbSession, session: models.Session, name: str) -> int | None:
    """The repetitions a set of exercise ``name`` asked in ``session``: the followed
    program version's, else the catalogue's; None for an exercise neither knows."""
    from ..programs.catalogue import CATALOGUE
    from ..programs.stream import followed_version

    version = followed_version(db, session.id)
    for entry in version.exercises if version is not None else ():
        if entry.exercise == name:
            return entry.repetitions
    known = CATALOGUE.get(name)
    return known.repetitions if known is not None else None


def _rom(db: DbSession, session: models.Session, poses: list[tuple[float, float]]
         ) -> dict[str, dict[str, Any]]:
    columns, values = stored_estimates(db, session)
    if not columns or not len(values):
        return {}
    t = values[:, columns.index("t")]
    # stored in degrees (``armtrack estimate``'s columns); the metrics take radians. Only
    # the angles the session's kit measures: the others are the spec's 0, not a finding
    # (docs/extensions/measured-angles.md)
    measured = set(session_coverage(session)["measured_angles"])
    angles = {name: np.deg2rad(values[:, columns.index(name)]) for name in REPORTED_ANGLES
              if name in columns and name in measured}
    # the report's rule (``calibration_exclusion``): the calibration the estimate used,
    # else the kit's pose marks
    used = [p["end"] for p in (session.calibration or {}).get("poses") or []]
    exclude = calibration_exclusion(float(t[0]), used or [b for _, b in poses]) or None
    try:
        table = range_of_motion_table(angles, t, exclude=exclude)
    except EstimatorError:
        return {}
    return {name: {**rom.to_report(), "moved": rom.moved} for name, rom in table.items()}


def _report_exercises(db: DbSession, session: models.Session) -> list[Any]:
    from ..reports import content

    try:
        return content.session_report(db, session, targets={}, current={}).exercises
    except content.NoEstimates:
        return []


def repetitions(exercise: Any) -> int:
    """A report exercise's repetitions: those counted on the catalogue's angle of a
    marked exercise (the programs' rule, ``docs/programs.md``), else on the angle that
    counted most."""
    from ..programs.catalogue import exercise as catalogue_entry

    entry = catalogue_entry(exercise.name) if exercise.source == "marks" else None
    counted = {a.angle: a.repetitions for a in exercise.angles}
    if entry is not None:
        return counted.get(entry.angle, 0)
    return max(counted.values(), default=0)


def detected_exercises(db: DbSession, session: models.Session) -> list[dict[str, Any]]:
    """The exercises the session's report detected (no marks), with their repetitions;
    none while it has no estimates."""
    return [{"name": e.name, "start": e.start_s, "end": e.end_s, "source": e.source,
             "repetitions": repetitions(e)} for e in _report_exercises(db, session)]


def count_marked(db: DbSession, session: models.Session,
                 exercises: list[dict[str, Any]]) -> None:
    """Gives each marked period the repetitions the session's report counted in it (the
    report's period of the same name starting at the same mark)."""
    counted = {(e.name, round(e.start_s, 3)): repetitions(e)
               for e in _report_exercises(db, session)
               if e.source == "marks" and e.start_s is not None}
    for exercise in exercises:
        found = counted.get((exercise["name"], round(exercise["start"], 3)))
        if found is not None:
            exercise["repetitions"] = found


def headline(rom: dict[str, dict[str, Any]]) -> str | None:
    """The largest range of motion in words: ``elbow flexion 0–118° (79% of normal)``."""
    rated = [(v["percent_of_normal"] or 0.0, v["range"], k) for k, v in rom.items()]
    if not rated:
        return None
    _, _, name = max(rated, key=lambda r: (r[1], r[0]))
    entry = rom[name]
    text = f"{name.replace('_', ' ')} {round(entry['min']) + 0}° to {round(entry['max']) + 0}°"
    if entry["percent_of_normal"] is not None:
        text += f" ({entry['percent_of_normal']:.0f}% of normal)"
    return text


def summarise(db: DbSession, session: models.Session) -> dict[str, Any]:
    key = (session.samples, session.status, len(session.estimate_columns or []),
           session.processing_error, repr(session.calibration))
    cached = _cache.get(session.id)
    if cached is not None and cached[0] == key and session.status == "closed":
        return cached[1]
    # one build per session at a time (it reads the whole session's estimates): a request
    # for it meanwhile takes this one's result
    return REPORTS.get(("summary", session.id, key), lambda: _summarise(db, session, key))


def _summarise(db: DbSession, session: models.Session, key: tuple) -> dict[str, Any]:
    cached = _cache.get(session.id)
    if cached is not None and cached[0] == key and session.status == "closed":
        return cached[1]  # built while this one waited
    totals = block_totals(db, session.id)
    end_t = max((v["t_last"] for v in totals.values()), default=None)
    start_t = min((v["t_first"] for v in totals.values()), default=None)
    exercises, poses = _periods(_marks(db, session.id), end_t)
    for exercise in exercises:
        exercise["source"] = "marks"
        # a set the kit began and never ended in a session now closed: the patient left it
        # part way (docs/therapist.md); how many a set asked, for "stopped after 4 of 10"
        if exercise.pop("ended", True) is False and session.status == "closed":
            exercise["unfinished"] = True
            exercise["asked"] = _asked_per_set(db, session, exercise["name"])
    rom = _rom(db, session, poses) if session.estimate_columns else {}
    if session.estimate_columns and session.status == "closed":
        if exercises:
            count_marked(db, session, exercises)
        else:
            exercises = detected_exercises(db, session)
    sensors = {name: {"samples": v["samples"],
                      "lost_fraction": lost_fraction(v, session.rate_hz)}
               for name, v in totals.items()}
    lost = [s["lost_fraction"] for s in sensors.values() if s["lost_fraction"] is not None]
    worst = max(lost, default=None)
    warnings = list((session.calibration or {}).get("warnings", []))
    missing = [s for s in session.sensors if s not in totals]
    duration = (end_t - start_t) if end_t is not None and start_t is not None else None
    short = (session.status == "closed" and duration is not None and duration < SHORT_S)
    if session.processing_error or missing or (worst is not None and worst > LOST_POOR):
        grade = "poor"
    elif warnings or short or (worst is not None and worst > LOST_FAIR):
        grade = "fair"
    else:
        grade = "good"
    summary = {
        "id": session.id, "patient_id": session.patient_id, "status": session.status,
        "source": session.source, "started_at": session.started_at.isoformat(),
        "ended_at": session.ended_at.isoformat() if session.ended_at else None,
        "duration_s": duration,
        "exercises": exercises,
        "calibration_poses": [{"start": a, "end": b} for a, b in poses],
        "rom": rom, "headline": headline(rom), "processed": bool(session.estimate_columns),
        **session_coverage(session),
        "processing_error": session.processing_error,
        "quality": {"grade": grade, "worst_lost_fraction": worst, "sensors": sensors,
                    "missing_sensors": missing, "calibration_warnings": warnings,
                    "short": short,
                    "calibration_method": (session.calibration or {}).get("method")},
    }
    if session.status == "closed":
        _cache.put(session.id, key, summary)
    return summary


@router.get("/sessions/{session_id}/summary")
def get_summary(session_id: Id, db: Db, therapist: Therapist, right: Held) -> dict[str, Any]:
    """Exercises, duration [s], range of motion [deg] against normal values (AAOS) of the
    angles the kit measures, calibration poses excluded, a ROM headline, the data quality,
    the kit's measured angles and assumptions (docs/extensions/measured-angles.md), and
    ``ratings``: the effort and pain the patient gave after each exercise
    (docs/extensions/effort-pain.md), in the order given."""
    session = own_session(db, therapist, session_id)
    return right.held({**summarise(db, session), "ratings": session_ratings(db, session.id)})


def session_ratings(db: DbSession, session_id: int) -> list[dict[str, Any]]:
    """The session's effort and pain ratings, ``{"exercise", "t", "effort", "pain"}`` each,
    in the order given (at most ``RATINGS_PER_SESSION_MAX``: one bounded query)."""
    rows = db.execute(select(models.SessionRating.exercise, models.SessionRating.t,
                             models.SessionRating.effort, models.SessionRating.pain)
                      .where(models.SessionRating.session_id == session_id)
                      .order_by(models.SessionRating.id))
    return [{"exercise": e, "t": t, "effort": effort, "pain": pain}
            for e, t, effort, pain in rows]


@router.get("/patients/{patient_id}/summaries")
def list_summaries(patient_id: Id, db: Db, therapist: Therapist, right: Held,
                   limit: Annotated[int, Query(ge=1, le=200)] = 50,
                   offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0) -> list[dict[str, Any]]:
    """The summaries of a patient's sessions, newest first."""
    own_patient(db, therapist, patient_id)
    with long_list(therapist, limit):
        sessions = db.scalars(select(models.Session)
                              .where(models.Session.patient_id == patient_id)
                              .order_by(models.Session.started_at.desc(),
                                        models.Session.id.desc())
                              .limit(limit).offset(offset))
        return right.held([summarise(db, s) for s in sessions])

