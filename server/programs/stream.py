"""The programs' extensions of the stream protocol (``ingest.md``, version 1):

* ``programs/1`` (``docs/extensions/programs-hello.md``): ``hello`` names a program of the
  patient (``"program": <id or name>``); ``ready`` gives its exercises and version, and
  the session is stored as following that version.
* ``effort-pain/1`` (``docs/extensions/effort-pain.md``): the device message
  ``effort_pain`` (effort on the Borg CR10 scale, pain on the 0–10 numeric rating scale,
  after an exercise), stored with the session and answered ``effort_pain_stored``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import date
from typing import Any

from armtrack.estimator.recording.model import LABEL_PATTERN
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session as DbSession
from sqlalchemy.orm import selectinload

from .. import clock
from ..db import models
from ..ingest.protocol import CLOSE_BAD_PROTOCOL, MARK_LABEL_MAX, Hello, Refused
from ..plain_text import text_problem
from ..reports.targets import Target, patient_targets, target_history, targets_at, targets_in
from . import catalogue, store
from .calendar import aware

PROGRAMS_EXTENSION = "programs/1"
EFFORT_PAIN_EXTENSION = "effort-pain/1"
#: The extensions of this module a server speaks.
SPOKEN = (PROGRAMS_EXTENSION, EFFORT_PAIN_EXTENSION)
RATING_ID_MAX = 64
#: The most ratings a session keeps: a rating per exercise and set is far fewer; a kit
#: sending more with new ids is refused rather than filling the table.
RATINGS_PER_SESSION_MAX = 200


def check_program(message: dict[str, Any], hello: Hello) -> int | str | None:
    """The program a ``hello`` names (``programs/1`` asked): its id or its name; None when
    it names none or did not ask for the extension (then ``program`` is an unknown field,
    ignored as before). A malformed one is refused like any bad hello (4400)."""
    if PROGRAMS_EXTENSION not in hello.extensions:
        return None
    ref = message.get("program")
    if ref is None:
        return None
    if isinstance(ref, int) and not isinstance(ref, bool) and 0 < ref < 2**31:
        return ref
    if isinstance(ref, str) and 0 < len(ref) <= 120:
        problem = text_problem(ref)  # the database cannot hold a lone surrogate or a NUL
        if problem is None:
            return ref
        raise Refused(f"hello: program must be valid text: {problem}",
                      close_code=CLOSE_BAD_PROTOCOL)
    raise Refused("hello: program must be a program's id or its name (1 to 120 "
                  f"characters), got {ref!r}", close_code=CLOSE_BAD_PROTOCOL)


def ready_program(db: DbSession, version: models.ProgramVersion) -> dict[str, Any]:
    """What ``ready`` says of the program version a session follows."""
    program = version.program
    targets = patient_targets(db, program.patient_id)
    exercises = []
    for e in version.exercises:
        entry = catalogue.CATALOGUE[e.exercise]
        (low, high), source = store.resolve_target(e, targets)
        exercises.append({
            "name": e.exercise, "title": entry.title, "angle": e.angle,
            "sensor": entry.sensor, "instruction": entry.instruction,
            "picture": entry.picture, "both_ways": entry.both_ways, "sets": e.sets,
            "repetitions": e.repetitions,
            "hold_s": e.hold_s, "rest_s": e.rest_s, "note": e.note,
            "target": {"min_deg": low, "max_deg": high, "from": source}})
    return {"id": program.id, "name": program.name, "version": version.number,
            "note": version.note, "exercises": exercises}


def follow_program(db: DbSession, patient_id: int, session_id: int, ref: int | str
                   ) -> tuple[dict[str, Any] | None, str | None]:
    """Link a new session to the current version of the patient's program ``ref`` (not
    committed); returns ``ready``'s ``program`` and, when there is none to follow, the
    reason (the session streams all the same)."""
    program = store.find_program(db, patient_id, ref)
    if program is None or not program.versions:
        return None, f"no program {ref!r} for this device's patient"
    if program.ended_at is not None:
        return None, f"program {program.name!r} has ended"
    version = program.versions[-1]
    db.add(models.SessionProgram(session_id=session_id, version_id=version.id))
    return ready_program(db, version), None


def followed_version(db: DbSession, session_id: int) -> models.ProgramVersion | None:
    """The program version a session follows since it started (its kit named the program
    in ``hello``), or None."""
    link = db.get(models.SessionProgram, session_id)
    return None if link is None else db.get(models.ProgramVersion, link.version_id)


def session_targets(db: DbSession, session: models.Session
                    ) -> tuple[dict[str, Target], dict[str, tuple[str, Target | None]]]:
    """What a session is judged against ("Target then"): per angle, and per exercise of
    the program version it followed (name → its angle and band, None without one).

    The patient's targets in force when it started (``targets_at``), and for a session
    that followed a program version, each exercise's band as the version gave it (the
    band the phone showed): the version's own, else the patient's target then. The
    catalogue's usual range is not a target (``resolve_target``'s last resort): such an
    exercise has none. Per angle, the band every exercise of the version on that angle
    shares; where two of them give it different bands (a forward and a side raise both
    move ``shoulder_elevation``) the angle has no one target and each exercise keeps its
    own."""
    return _judged_against(targets_at(db, session.patient_id, aware(session.started_at)),
                           followed_version(db, session.id))


def sessions_targets(db: DbSession, patient_id: int, sessions: Sequence[models.Session]
                     ) -> dict[int, tuple[dict[str, Target], dict[str, tuple[str, Target | None]]]]:
    """``session_targets`` of many sessions of one patient (session id → the pair), in a
    few queries however many there are (the progress list: one read of the patient's
    target history, of the sessions' program links, of the versions they followed and of
    those versions' exercises)."""
    history = target_history(db, patient_id)
    links: dict[int, int] = {}
    ids = [s.id for s in sessions]
    for start in range(0, len(ids), 500):  # SQLite's bound parameters, in chunks
        links.update((session_id, version_id) for session_id, version_id in db.execute(
            select(models.SessionProgram.session_id, models.SessionProgram.version_id)
            .where(models.SessionProgram.session_id.in_(ids[start:start + 500]))))
    versions = {v.id: v for v in db.scalars(
        select(models.ProgramVersion)
        .where(models.ProgramVersion.id.in_(set(links.values())))
        .options(selectinload(models.ProgramVersion.exercises)))} if links else {}
    return {s.id: _judged_against(targets_in(history, aware(s.started_at)),
                                  versions.get(links.get(s.id, -1)))
            for s in sessions}


def with_band_done(targets: dict[str, Target], bands: dict[str, tuple[str, Target | None]],
                   done: Iterable[str]) -> dict[str, Target]:
    """``targets`` (``session_targets``' per angle) with, for an angle two exercises of
    the followed version give different bands, the band of the one the session did
    (``done``: its exercises' names) when it did only one of them: its range is that
    exercise's. A session that did both keeps none there (its range spans both)."""
    done = set(done)
    out = dict(targets)
    for angle in {a for a, _ in bands.values()} - set(out):
        did = [band for name, (a, band) in bands.items() if a == angle and name in done]
        if len(did) == 1 and did[0] is not None:
            out[angle] = did[0]
    return dict(sorted(out.items()))


def _judged_against(base: dict[str, Target], version: models.ProgramVersion | None
                    ) -> tuple[dict[str, Target], dict[str, tuple[str, Target | None]]]:
    if version is None:
        return base, {}
    bands: dict[str, tuple[str, Target | None]] = {}
    for e in version.exercises:
        if e.target_min_deg is not None and e.target_max_deg is not None:
            band: Target | None = Target(angle=e.angle, min_deg=e.target_min_deg,
                                         max_deg=e.target_max_deg, note=None,
                                         set_at=aware(version.created_at))
        else:
            band = base.get(e.angle)
        bands[e.exercise] = (e.angle, band)
    by_angle = dict(base)
    for angle in {a for a, _ in bands.values()}:
        given = {None if b is None else (b.min_deg, b.max_deg)
                 for a, b in bands.values() if a == angle}
        if len(given) == 1:
            only = next(b for a, b in bands.values() if a == angle)
            if only is None:
                by_angle.pop(angle, None)
            else:
                by_angle[angle] = only
        else:
            by_angle.pop(angle, None)
    return dict(sorted(by_angle.items())), bands


def followed_program(db: DbSession, session_id: int) -> dict[str, Any] | None:
    """``ready``'s ``program`` for a session continued or resumed: the version it follows
    since it started (never a newer one)."""
    version = followed_version(db, session_id)
    return None if version is None else ready_program(db, version)


@dataclass(frozen=True)
class EffortPain:
    id: str
    exercise: str
    t: float | None
    effort: float | None
    pain: int | None


def check_effort_pain(message: dict[str, Any]) -> EffortPain:
    """An ``effort_pain`` message, checked whole: ``id`` (the kit's, 1–64 characters),
    ``exercise`` (a mark label's name), optional ``t`` [s, the stream's clock], ``effort``
    0–10 in steps of 0.5 (Borg CR10) and ``pain`` 0–10 whole (NRS), at least one given."""
    def bad(reason: str) -> Refused:
        return Refused(f"effort_pain: {reason}")

    rid = message.get("id")
    if not isinstance(rid, str) or not 0 < len(rid) <= RATING_ID_MAX:
        raise bad(f"id must be the kit's id of this message, 1 to {RATING_ID_MAX} "
                  "characters")
    problem = text_problem(rid)  # stored with the rating: no lone surrogate, no NUL
    if problem:
        raise bad(f"id must be valid text: {problem}")
    exercise = message.get("exercise")
    if isinstance(exercise, str) and len(f"exercise:{exercise}") > MARK_LABEL_MAX:
        raise bad(f"exercise must be the name the kit marked, a mark's label being at most "
                  f"{MARK_LABEL_MAX} characters; got {len(exercise)}")
    if not isinstance(exercise, str) or not LABEL_PATTERN.fullmatch(f"exercise:{exercise}"):
        raise bad(f"exercise must be the name the kit marked (exercise:<name>), got "
                  f"{exercise!r}")
    t = message.get("t")
    if t is not None and not (_number(t) and 0 <= t < 1e9):
        raise bad(f"t must be a time [s] on the stream's clock, got {t!r}")
    effort, pain = message.get("effort"), message.get("pain")
    if effort is not None and not (_number(effort) and 0 <= effort <= 10
                                   and float(effort * 2).is_integer()):
        raise bad(f"effort must be 0 to 10 in steps of 0.5 (Borg CR10), got {effort!r}")
    if pain is not None and not (isinstance(pain, int) and not isinstance(pain, bool)
                                 and 0 <= pain <= 10):
        raise bad(f"pain must be a whole number 0 to 10 (numeric rating scale), got "
                  f"{pain!r}")
    if effort is None and pain is None:
        raise bad("give effort, pain or both")
    return EffortPain(rid, exercise, None if t is None else float(t),
                      None if effort is None else float(effort), pain)


def _number(value: Any) -> bool:
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value))


def store_effort_pain(db: DbSession, session_id: int, rating: EffortPain) -> bool:
    """Store a rating with its session (committed); False when that id was stored
    already (a message sent again): the first one stands. Refused past
    ``RATINGS_PER_SESSION_MAX`` ratings in the session."""
    exists = db.scalar(select(models.SessionRating.id).where(
        models.SessionRating.session_id == session_id,
        models.SessionRating.rating_id == rating.id))
    if exists is not None:
        return False
    kept = db.scalar(select(func.count()).select_from(models.SessionRating).where(
        models.SessionRating.session_id == session_id))
    if kept >= RATINGS_PER_SESSION_MAX:
        raise Refused(f"effort_pain: this session keeps {RATINGS_PER_SESSION_MAX} ratings "
                      "already, the most a session keeps; this one is not stored")
    db.add(models.SessionRating(session_id=session_id, rating_id=rating.id,
                                exercise=rating.exercise, t=rating.t, effort=rating.effort,
                                pain=rating.pain, received_at=clock.now()))
    try:
        db.commit()
    except IntegrityError:  # the same id from a second connection at the same moment
        db.rollback()
        return False
    return True


def todays_program(db: DbSession, patient_id: int, today: date
                   ) -> models.Program | None:
    """The program a kit guides today: the most recently created one in force today
    (``store.is_active``), or None."""
    active = [p for p in store.patient_programs(db, patient_id) if store.is_active(p, today)]
    return active[-1] if active else None


def device_today(db: DbSession, patient: models.Patient, today: date) -> dict[str, Any] | None:
    """What the device-scoped read of today's exercises (the phone kit's
    ``docs/extensions/device-today.md``) answers when a program is in force: ``source``
    ``program``, the program's id, name and version (the kit names it in ``hello``,
    ``programs-hello.md``), and its exercises in order, each the catalogue's fields with
    the dose (and the days a week it is prescribed), the target band and what a phone
    measures it on (``catalogue.phone_fields``); None without a program in force."""
    program = todays_program(db, patient.id, today)
    if program is None:
        return None
    version = program.versions[-1]
    ready = ready_program(db, version)
    exercises = []
    # how often, for the patient's welcome ("5 days a week"); `ready` has no need of it
    for e, prescribed in zip(ready["exercises"], version.exercises, strict=True):
        entry = catalogue.CATALOGUE[e["name"]]
        exercises.append({**entry.as_dict(), **e, **catalogue.phone_fields(entry),
                          "days_per_week": prescribed.days_per_week})
    return {"source": "program", "side": patient.side,
            "program": {"id": program.id, "name": program.name,
                        "version": ready["version"], "note": ready["note"],
                        "changed_at": aware(version.created_at)},
            "exercises": exercises}
