"""What a patient did in their own recent sessions, for their phone (device-today's
``recent``, ``docs/extensions/device-today.md``): per session its start, the program it
followed and, per exercise the kit marked, the repetitions counted on the exercise's
angle against those prescribed, and the range reached [deg] beside the target then — the
numbers of the phone's finished screen ("What you did"), taken from the session's report
as the therapist's pages take them (``adherence.session_results``, cached per estimate).

Only the given patient's sessions are read; only estimated sessions with a marked
exercise are told (a session being processed, or without marks, has nothing to say yet),
and only those have their report built: the phone asks at every page load, and six long
unmarked uploads cost 18.9 s of the server there after a restart (attack13)."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..reports.targets import targets_at
from .adherence import ExerciseResult, session_results
from .calendar import aware
from .catalogue import CATALOGUE
from .store import resolve_target
from .stream import followed_version

#: Sessions told at most, newest first.
RECENT_SESSIONS = 3
#: Estimated sessions looked at for them at most (each a report built once, then cached).
RECENT_LOOKED_AT = 6


def recent_sessions(db: DbSession, patient_id: int) -> list[dict[str, Any]]:
    """The patient's latest estimated sessions with a marked exercise, newest first (at
    most ``RECENT_SESSIONS``): ``{"session_id", "started_at" [UTC], "program": {"name",
    "version"} | None, "exercises": [{"name", "title", "angle", "repetitions", "prescribed",
    "min_deg", "max_deg", "target": {"min_deg", "max_deg"}}]}``."""
    marked = select(models.Mark.id).where(models.Mark.session_id == models.Session.id,
                                          models.Mark.label.startswith("exercise:"))
    sessions = db.scalars(  # one without an exercise mark tells nothing: no report built
        select(models.Session)
        .where(models.Session.patient_id == patient_id,
               models.Session.estimate_columns.is_not(None), marked.exists())
        .order_by(models.Session.started_at.desc(), models.Session.id.desc())
        .limit(RECENT_LOOKED_AT))
    out = []
    for session in sessions:
        results = session_results(db, session)
        if not results:
            continue
        out.append(_told(db, session, results))
        if len(out) == RECENT_SESSIONS:
            break
    return out


def _told(db: DbSession, session: models.Session, results: dict[str, ExerciseResult]
          ) -> dict[str, Any]:
    version = followed_version(db, session.id)
    prescribed = {e.exercise: e for e in version.exercises} if version is not None else {}
    targets = targets_at(db, session.patient_id, aware(session.started_at))
    # the program's order first (as the phone listed them), then the others as done
    names = [n for n in prescribed if n in results] + [n for n in results
                                                        if n not in prescribed]
    exercises = []
    for name in names:
        entry, result = CATALOGUE[name], results[name]
        if name in prescribed:
            e = prescribed[name]
            (low, high), source = resolve_target(e, targets)
            count = e.sets * e.repetitions
        else:
            target = targets.get(entry.angle)
            low, high = ((target.min_deg, target.max_deg) if target is not None
                         else (entry.rest_deg, entry.target_deg))
            source = "patient" if target is not None else "default"
            count = entry.repetitions
        exercises.append({"name": name, "title": entry.title, "angle": entry.angle,
                          "repetitions": result.repetitions, "prescribed": count,
                          "min_deg": result.min_deg, "max_deg": result.max_deg,
                          "target": {"min_deg": low, "max_deg": high, "from": source}})
    return {"session_id": session.id, "started_at": aware(session.started_at),
            "program": (None if version is None else
                        {"name": version.program.name, "version": version.number}),
            "exercises": exercises}
