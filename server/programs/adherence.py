"""Adherence, progress and flags of a patient's programs, computed exactly as
``docs/programs.md`` words them (the tests derive their expected numbers from those words).

Per session and program exercise, the numbers come from the session's report
(``reports/content.py``): the report's marked exercises named like the program's, the
repetitions counted on the catalogue's angle, and the range of motion of that angle in
each marked period. Days are the clinic's (``calendar.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import date, datetime, timedelta
from typing import Any
from zoneinfo import ZoneInfo

import numpy as np
from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession
from sqlalchemy.orm import selectinload

from .. import clock
from ..db import models
from ..lru import BoundedLru
from ..reports import content
from ..reports.content import NoEstimates
from ..reports.targets import targets_at
from ..settings import Settings
from . import catalogue, store
from .calendar import aware, clinic_zone, local_day, monday, start_of_day, week_name

SECONDS_PER_WEEK = 7 * 24 * 3600.0


# --- what the API answers -------------------------------------------------------------

class Counts(BaseModel):
    sessions: int
    days: int
    exercises: int = Field(description="exercise-days")
    repetitions: int


class Shortened(BaseModel):
    starts_on: date | None = Field(description="the program's first day, within the week")
    ends_on: date | None = Field(description="the program's last day, within the week")


class WeekAdherence(BaseModel):
    week: str = Field(description="ISO week, e.g. 2026-W49")
    monday: date
    version: int = Field(description="the version whose prescription the week follows")
    active_days: int = Field(description="days of the week within that version's dates")
    prescribed: Counts
    done: Counts
    adherence_percent: float | None = Field(
        description="100 × Σ min(done, prescribed repetitions) per exercise ÷ prescribed")
    shortened: Shortened | None = Field(
        None, description="null unless the program's dates leave fewer days in the week "
        "than its exercises' days a week (it starts or ends within the week)")
    changed_on: date | None = Field(
        None, description="the day a version asking another number of days a week was "
        "saved in the week, else null: the week keeps the version in force on its Monday "
        "(for the program's first week, the first version), the change counts from the "
        "next week")


class ExercisePoint(BaseModel):
    session_id: int
    day: date
    started_at: datetime
    version: int
    repetitions: int
    range_deg: float | None = Field(description="the largest of its periods' ranges [deg]")
    min_deg: float | None
    max_deg: float | None
    target_min_deg: float
    target_max_deg: float
    target_source: str = Field(description="program, patient or catalogue")
    target_reached: bool | None


class ExerciseProgress(BaseModel):
    exercise: str
    title: str
    angle: str
    points: list[ExercisePoint] = Field(description="sessions it was done in, oldest first")


class PainPoint(BaseModel):
    session_id: int
    day: date
    started_at: datetime
    pain: int | None = Field(description="highest pain given in the session (NRS 0–10)")
    effort: float | None = Field(description="highest effort given (Borg CR10 0–10)")


class Flag(BaseModel):
    kind: str = Field(description="no_session, range_falling or pain_rising")
    program_id: int | None
    exercise: str | None
    value: float = Field(description="days, deg/week or points/week")
    message: str


class ProgramSessionOut(BaseModel):
    session_id: int
    day: date
    started_at: datetime
    version: int
    how: str = Field(description="hello (the kit named the program) or attributed")


class ProgramProgress(BaseModel):
    program_id: int
    name: str
    active: bool
    version: int = Field(description="the current version's number")
    sessions: list[ProgramSessionOut]
    weeks: list[WeekAdherence]
    exercises: list[ExerciseProgress]
    pain: list[PainPoint]
    flags: list[Flag]
    uncounted_sessions: int = Field(
        0, description="closed sessions of the patient from the program's first day (to its "
        "end) that count toward no program: their kit neither named a program in hello nor "
        "marked an exercise of one (docs/programs.md)")


# --- gathering the sessions -----------------------------------------------------------

@dataclass
class ExerciseResult:
    repetitions: int = 0
    range_deg: float | None = None
    min_deg: float | None = None
    max_deg: float | None = None


@dataclass
class ProgramSession:
    session: models.Session
    version: models.ProgramVersion
    how: str
    day: date
    results: dict[str, ExerciseResult] = field(default_factory=dict)
    pain: int | None = None
    effort: float | None = None

    @property
    def started_at(self) -> datetime:
        return aware(self.session.started_at)


def exercise_results(report: content.SessionReport) -> dict[str, ExerciseResult]:
    """Per catalogue exercise marked in the session: repetitions on its angle summed over
    its periods, the largest period range, the lowest minimum and highest maximum."""
    out: dict[str, ExerciseResult] = {}
    for ex in report.exercises:
        entry = catalogue.CATALOGUE.get(ex.name)
        if ex.source != "marks" or entry is None:
            continue
        result = out.setdefault(ex.name, ExerciseResult())
        result.repetitions += sum(a.repetitions for a in ex.angles if a.angle == entry.angle)
        rom = ex.rom.get(entry.angle)
        if rom is not None:
            result.range_deg = max(rom.range, result.range_deg or -np.inf)
            result.min_deg = min(rom.min, np.inf if result.min_deg is None else result.min_deg)
            result.max_deg = max(rom.max, -np.inf if result.max_deg is None
                                 else result.max_deg)
    return out


def _marked_exercises(db: DbSession, session_ids: Sequence[int]) -> dict[int, set[str]]:
    rows = db.execute(select(models.Mark.session_id, models.Mark.label).where(
        models.Mark.session_id.in_(session_ids), models.Mark.label.like("exercise:%")))
    out: dict[int, set[str]] = {}
    for session_id, label in rows:
        out.setdefault(session_id, set()).add(label.removeprefix("exercise:"))
    return out


def patient_sessions(db: DbSession, patient_id: int) -> list[models.Session]:
    """The patient's sessions, oldest first."""
    return list(db.scalars(select(models.Session)
                           .where(models.Session.patient_id == patient_id)
                           .order_by(models.Session.started_at, models.Session.id)))


def program_sessions(db: DbSession, patient_id: int, programs: Sequence[models.Program],
                     zone: ZoneInfo, sessions: Sequence[models.Session] | None = None
                     ) -> dict[int, list[ProgramSession]]:
    """Program id → its sessions, oldest first: those whose kit named it in ``hello``,
    and those attributed to it (no program named, a marked exercise of the version in
    force at the start; the most recently created such program). ``sessions``: the
    patient's (``patient_sessions``) when already read."""
    if sessions is None:
        sessions = patient_sessions(db, patient_id)
    links, marked = _links_and_marks(db, sessions)
    return _attributed(sessions, programs, links, marked, zone)


def _links_and_marks(db: DbSession, sessions: Sequence[models.Session]
                     ) -> tuple[dict[int, int], dict[int, set[str]]]:
    """The program versions sessions named (session id → version id), and the marked
    exercises of the others."""
    links = dict(db.execute(select(models.SessionProgram.session_id,
                                   models.SessionProgram.version_id).where(
        models.SessionProgram.session_id.in_([s.id for s in sessions]))).all())
    return links, _marked_exercises(db, [s.id for s in sessions if s.id not in links])


def _attributed(sessions: Sequence[models.Session], programs: Sequence[models.Program],
                links: Mapping[int, int], marked: Mapping[int, set[str]], zone: ZoneInfo
                ) -> dict[int, list[ProgramSession]]:
    """``program_sessions`` of one patient's ``sessions`` (oldest first)."""
    versions = {v.id: (p, v) for p in programs for v in p.versions}
    out: dict[int, list[ProgramSession]] = {p.id: [] for p in programs}
    newest_first = sorted(programs, key=lambda p: (aware(p.created_at), p.id), reverse=True)
    for s in sessions:
        found = None
        if s.id in links:
            if links[s.id] in versions:
                found = (*versions[links[s.id]], "hello")
        else:
            names = marked.get(s.id, set())
            for p in newest_first:
                v = store.version_in_force(p, aware(s.started_at))
                if v is not None and names & {e.exercise for e in v.exercises}:
                    found = (p, v, "attributed")
                    break
        if found is not None:
            program, version, how = found
            out[program.id].append(ProgramSession(s, version, how,
                                                  local_day(s.started_at, zone)))
    return out


def _fill(db: DbSession, items: Sequence[ProgramSession]) -> None:
    """Each session's exercise results (from its report) and its highest pain/effort."""
    ratings = db.execute(select(models.SessionRating.session_id, models.SessionRating.pain,
                                models.SessionRating.effort).where(
        models.SessionRating.session_id.in_([i.session.id for i in items])))
    pains: dict[int, list[int]] = {}
    efforts: dict[int, list[float]] = {}
    for session_id, pain, effort in ratings:
        if pain is not None:
            pains.setdefault(session_id, []).append(pain)
        if effort is not None:
            efforts.setdefault(session_id, []).append(effort)
    for item in items:
        sid = item.session.id
        item.pain = max(pains[sid]) if sid in pains else None
        item.effort = max(efforts[sid]) if sid in efforts else None
        item.results = session_results(db, item.session)


#: Exercise results of sessions, by what identifies their estimates (the report cache's
#: key: a new estimate, reprocessing, a resumed stream make a new key): a few numbers a
#: session, so that the flags of every patient need no report built again.
_RESULTS: BoundedLru[tuple, dict[str, ExerciseResult]] = BoundedLru(50_000)


def session_results(db: DbSession, session: models.Session) -> dict[str, ExerciseResult]:
    """``exercise_results`` of the session's report ({} while it has no estimates)."""
    key = content.report_key(session)
    if (found := _RESULTS.get(key)) is not None:
        return found
    try:  # the results need no targets: none are looked up
        found = exercise_results(content.session_report(db, session, {}, current={}))
    except NoEstimates:
        found = {}
    _RESULTS.put(key, found)
    return found


# --- adherence ------------------------------------------------------------------------

def prescription_version(program: models.Program, week_monday: date, zone: ZoneInfo
                         ) -> models.ProgramVersion:
    """The version in force at the start of the week's Monday; before any was, the
    first."""
    return store.version_in_force(program, start_of_day(week_monday, zone)) \
        or program.versions[0]


def active_dates(program: models.Program, version: models.ProgramVersion,
                 week_monday: date, zone: ZoneInfo) -> list[date]:
    """The days of the week of ``week_monday`` within ``version``'s dates (and before the
    program was ended), in order."""
    last = version.end_date
    if program.ended_at is not None:
        ended = local_day(program.ended_at, zone)
        last = ended if last is None else min(last, ended)
    days = [week_monday + timedelta(days=i) for i in range(7)]
    return [d for d in days if version.start_date <= d and (last is None or d <= last)]


def active_days(program: models.Program, version: models.ProgramVersion,
                week_monday: date, zone: ZoneInfo) -> int:
    return len(active_dates(program, version, week_monday, zone))


def last_week(program: models.Program, today: date, zone: ZoneInfo) -> date:
    """The Monday of the last week listed: today's, or the end date's if earlier."""
    end = program.versions[-1].end_date
    if program.ended_at is not None:
        ended = local_day(program.ended_at, zone)
        end = ended if end is None else min(end, ended)
    return monday(min(today, end) if end is not None else today)


@dataclass(frozen=True)
class WeekDays:
    """A program's week by days (``docs/programs.md``, "Adherence"): the version whose
    prescription the week follows, its active days, the days asked (``prescribed.days``:
    ``min(max_e days_per_week_e, active days)``) and the days done (``done.days``: distinct
    clinic days with a program session)."""

    version: models.ProgramVersion
    active: int
    asked: int
    done: int
    in_week: list[ProgramSession]
    #: why the days asked are not the "N days a week" the program's list says: its dates
    #: leave fewer days in the week (``Shortened``), or a version asking another N was
    #: saved in the week (``changed_on``: the week keeps Monday's)
    shortened: Shortened | None = None
    changed_on: date | None = None


def week_days(program: models.Program, items: Sequence[ProgramSession], week: date,
              zone: ZoneInfo) -> WeekDays:
    """The days of the week of Monday ``week``, from the program's sessions ``items``
    (their results are not needed): the one rule of the therapist's weeks (``weeks``) and
    of the patient's phone (``this_week``)."""
    version = prescription_version(program, week, zone)
    dates = active_dates(program, version, week, zone)
    in_week = [i for i in items if week <= i.day < week + timedelta(days=7)]
    per_week = max(e.days_per_week for e in version.exercises)
    asked = min(per_week, len(dates))
    shortened = None
    if dates and asked < per_week:
        shortened = Shortened(
            starts_on=dates[0] if dates[0] > week else None,
            ends_on=dates[-1] if dates[-1] < week + timedelta(days=6) else None)
    start, stop = start_of_day(week, zone), start_of_day(week + timedelta(days=7), zone)
    newer = [v for v in program.versions
             if v.number > version.number and start <= aware(v.created_at) < stop]
    changed_on = local_day(newer[-1].created_at, zone) if newer and max(
        e.days_per_week for e in newer[-1].exercises) != per_week else None
    return WeekDays(version, len(dates), asked, len({i.day for i in in_week}), in_week,
                    shortened, changed_on)


def weeks(program: models.Program, items: Sequence[ProgramSession], today: date,
          zone: ZoneInfo) -> list[WeekAdherence]:
    out = []
    week = monday(program.versions[0].start_date)
    stop = last_week(program, today, zone)
    while week <= stop:
        days = week_days(program, items, week, zone)
        version, active, in_week = days.version, days.active, days.in_week
        per_e = {e.exercise: min(e.days_per_week, active) for e in version.exercises}
        prescribed_reps = {e.exercise: per_e[e.exercise] * e.sets * e.repetitions
                           for e in version.exercises}
        sessions_prescribed = days.asked
        done_reps = {name: sum(i.results[name].repetitions for i in in_week
                               if name in i.results) for name in per_e}
        done_days = {name: len({i.day for i in in_week if name in i.results
                                and i.results[name].repetitions > 0}) for name in per_e}
        total = sum(prescribed_reps.values())
        capped = sum(min(done_reps[n], prescribed_reps[n]) for n in per_e)
        out.append(WeekAdherence(
            week=week_name(week), monday=week, version=version.number, active_days=active,
            prescribed=Counts(sessions=sessions_prescribed, days=sessions_prescribed,
                              exercises=sum(per_e.values()), repetitions=total),
            done=Counts(sessions=len(in_week), days=days.done,
                        exercises=sum(done_days.values()),
                        repetitions=sum(done_reps.values())),
            adherence_percent=round(100.0 * capped / total, 1) if total else None,
            shortened=days.shortened, changed_on=days.changed_on))
        week += timedelta(days=7)
    return out


def this_week(db: DbSession, patient_id: int, program: models.Program, today: date,
              zone: ZoneInfo) -> dict[str, Any]:
    """The patient's phone's count of this week (``docs/extensions/device-today.md``,
    ``this_week``): the week of the clinic's ``today`` as the therapist's adherence counts
    it (``week_days``), ``{"week", "monday", "days_done", "days_asked", "today_done",
    "shortened"}``; ``shortened``: when the program's dates leave fewer days in the week
    than its exercises ask, ``{"starts_on", "ends_on"}`` (the program's first day where it
    falls inside the week and is not after today, its last where inside the week and not
    before today, else null), so the phone can say why; else (or when neither is true
    today: the therapist changed the dates since the week's Monday) null; ``changed_on``:
    the day a version asking another number of days was saved this week (the week keeps
    Monday's), else null.
    Bounded: the patient's programs, the sessions that started in the week (with a day's
    margin each side; the clinic's days decide), their program links and marks — four
    queries, no report built (days need none)."""
    week = monday(today)
    programs = [p for p in store.patient_programs(db, patient_id) if p.versions]
    sessions = list(db.scalars(
        select(models.Session)
        .where(models.Session.patient_id == patient_id,
               models.Session.started_at >= start_of_day(week - timedelta(days=1), zone),
               models.Session.started_at < start_of_day(week + timedelta(days=8), zone))
        .order_by(models.Session.started_at, models.Session.id)))
    links, marked = _links_and_marks(db, sessions)
    items = _attributed(sessions, programs, links, marked, zone).get(program.id, [])
    days = week_days(program, items, week, zone)
    # only what is true today: the week follows its Monday's version, whose dates the
    # therapist may have changed since (an end put off, a start brought forward)
    shortened = None
    if days.shortened is not None:
        first, last = days.shortened.starts_on, days.shortened.ends_on
        starts_on = first if first is not None and first <= today else None
        ends_on = last if last is not None and today <= last else None
        if starts_on or ends_on:
            shortened = {"starts_on": starts_on, "ends_on": ends_on}
    return {"week": week_name(week), "monday": week, "days_done": days.done,
            "days_asked": days.asked, "today_done": any(i.day == today for i in days.in_week),
            "shortened": shortened, "changed_on": days.changed_on}


# --- progress -------------------------------------------------------------------------

def exercise_progress(program: models.Program, items: Sequence[ProgramSession],
                      targets_for: Callable[[datetime], Mapping[str, Any]]
                      ) -> list[ExerciseProgress]:
    """Per exercise of any version (the current version's order first); each session
    against the target in force when it started (``targets_for(started_at)``: the
    patient's targets then)."""
    order: dict[str, None] = {}
    for v in reversed(program.versions):
        order.update(dict.fromkeys(e.exercise for e in v.exercises))
    out = []
    for name in order:
        entry = catalogue.CATALOGUE.get(name)
        if entry is None:
            continue
        points = []
        for i in items:
            r = i.results.get(name)
            if r is None or r.repetitions <= 0:
                continue
            prescribed = next((e for e in i.version.exercises if e.exercise == name), None)
            if prescribed is not None:
                (tmin, tmax), source = store.resolve_target(prescribed,
                                                            targets_for(i.started_at))
            else:
                tmin, tmax, source = entry.rest_deg, entry.target_deg, "catalogue"
            reached = (None if r.min_deg is None else
                       bool(r.min_deg <= tmin and r.max_deg >= tmax))
            points.append(ExercisePoint(
                session_id=i.session.id, day=i.day, started_at=i.started_at,
                version=i.version.number, repetitions=r.repetitions, range_deg=r.range_deg,
                min_deg=r.min_deg, max_deg=r.max_deg, target_min_deg=tmin,
                target_max_deg=tmax, target_source=source, target_reached=reached))
        out.append(ExerciseProgress(exercise=name, title=entry.title, angle=entry.angle,
                                    points=points))
    return out


# --- flags ----------------------------------------------------------------------------

def slope_per_week(times: Sequence[datetime], values: Sequence[float]) -> float:
    """Least-squares slope of ``values`` against the times, per week."""
    t = np.array([m.timestamp() for m in times])
    return float(np.polyfit(t, np.asarray(values, dtype=float), 1)[0]) * SECONDS_PER_WEEK


def program_flags(program: models.Program, items: Sequence[ProgramSession], today: date,
                  settings: Settings) -> list[Flag]:
    """``range_falling`` per exercise of the current version and ``pain_rising``, over
    the window of the last ``flag_window_days`` days (counting today)."""
    if not store.is_active(program, today):
        return []
    first_day = today - timedelta(days=settings.flag_window_days - 1)
    window = [i for i in items if first_day <= i.day <= today]
    out = []
    for e in program.versions[-1].exercises:
        done = [(i.started_at, i.results[e.exercise].range_deg) for i in window
                if e.exercise in i.results and i.results[e.exercise].repetitions > 0
                and i.results[e.exercise].range_deg is not None]
        if len(done) >= settings.flag_min_sessions:
            slope = slope_per_week([d[0] for d in done], [d[1] for d in done])
            if slope <= -settings.flag_range_drop_deg_per_week:
                title = catalogue.CATALOGUE[e.exercise].title
                out.append(Flag(kind="range_falling", program_id=program.id,
                                exercise=e.exercise, value=round(slope, 2),
                                message=f"{title}: range {slope:+.1f}° a week over "
                                        f"{len(done)} sessions"))
    rated = [(i.started_at, i.pain) for i in window if i.pain is not None]
    if len(rated) >= settings.flag_min_sessions:
        slope = slope_per_week([r[0] for r in rated], [r[1] for r in rated])
        if slope >= settings.flag_pain_rise_per_week:
            out.append(Flag(kind="pain_rising", program_id=program.id, exercise=None,
                            value=round(slope, 2),
                            message=f"pain {slope:+.1f} points a week over {len(rated)} "
                                    "sessions"))
    return out


def no_session_flag(db: DbSession, patient_id: int, programs: Sequence[models.Program],
                    today: date, zone: ZoneInfo, settings: Settings) -> Flag | None:
    if not any(store.is_active(p, today) for p in programs):
        return None
    last = db.scalar(select(models.Session.started_at)
                     .where(models.Session.patient_id == patient_id)
                     .order_by(models.Session.started_at.desc()).limit(1))
    return _no_session(last, programs, today, zone, settings)


def _no_session(last: datetime | None, programs: Sequence[models.Program], today: date,
                zone: ZoneInfo, settings: Settings) -> Flag | None:
    """The ``no_session`` flag, given the start of the patient's last session (None: no
    session yet)."""
    active = [p for p in programs if store.is_active(p, today)]
    if not active:
        return None
    since = (local_day(last, zone) if last is not None
             else min(p.versions[-1].start_date for p in active))
    days = (today - since).days
    if days < settings.flag_no_session_days:
        return None
    words = "since the program started" if last is None else "since the last session"
    return Flag(kind="no_session", program_id=None, exercise=None, value=days,
                message=f"no session for {days} days ({words})")


def filled_sessions(db: DbSession, patient_id: int, program: models.Program,
                    zone: ZoneInfo) -> list[ProgramSession]:
    """The sessions of ``program`` with their results, pain and effort (the patient's
    other programs decide the attribution)."""
    programs = [p for p in store.patient_programs(db, patient_id) if p.versions]
    items = program_sessions(db, patient_id, programs, zone).get(program.id, [])
    _fill(db, items)
    return items


# --- together -------------------------------------------------------------------------

def flags_by_patient(db: DbSession, patient_ids: Sequence[int], settings: Settings,
                     now: datetime | None = None) -> dict[int, list[Flag]]:
    """Each patient's flags (those with none left out), as ``patient_programs_progress``
    gives them per program, the ``no_session`` flag once (on the first active program);
    without the weeks and progress the flags do not need, and in a few queries for all
    the patients (their sessions' results come from ``session_results``)."""
    zone = clinic_zone(settings.clinic_timezone)
    today = local_day(now or clock.now(), zone)
    programs: dict[int, list[models.Program]] = {}
    for p in db.scalars(select(models.Program)
                        .where(models.Program.patient_id.in_(patient_ids))
                        .options(selectinload(models.Program.versions)
                                 .selectinload(models.ProgramVersion.exercises))
                        .order_by(models.Program.created_at, models.Program.id)):
        if p.versions:
            programs.setdefault(p.patient_id, []).append(p)
    flagged = [pid for pid in patient_ids
               if any(store.is_active(p, today) for p in programs.get(pid, ()))]
    sessions: dict[int, list[models.Session]] = {pid: [] for pid in flagged}
    for s in db.scalars(select(models.Session)
                        .where(models.Session.patient_id.in_(flagged))
                        .order_by(models.Session.started_at, models.Session.id)):
        sessions[s.patient_id].append(s)
    links, marked = _links_and_marks(db, [s for v in sessions.values() for s in v])
    by_patient = {pid: _attributed(sessions[pid], programs[pid], links, marked, zone)
                  for pid in flagged}
    _fill(db, [i for pid in flagged for p in programs[pid] if store.is_active(p, today)
               for i in by_patient[pid][p.id]])
    out: dict[int, list[Flag]] = {}
    for pid in flagged:
        active = [p for p in programs[pid] if store.is_active(p, today)]
        last = max((s.started_at for s in sessions[pid]), default=None, key=aware)
        missed = _no_session(last, programs[pid], today, zone, settings)
        flags = [] if missed is None else [missed.model_copy(update={"program_id":
                                                                    active[0].id})]
        for p in programs[pid]:
            flags += program_flags(p, by_patient[pid][p.id], today, settings)
        if flags:
            out[pid] = flags
    return out


def patient_programs_progress(db: DbSession, patient: models.Patient, settings: Settings,
                              now: datetime | None = None) -> list[ProgramProgress]:
    """Every program of the patient with its sessions, weeks, progress, pain and flags
    (the patient's ``no_session`` flag on each active program)."""
    zone = clinic_zone(settings.clinic_timezone)
    today = local_day(now or clock.now(), zone)
    programs = [p for p in store.patient_programs(db, patient.id) if p.versions]
    if not programs:
        return []
    sessions = patient_sessions(db, patient.id)
    by_program = program_sessions(db, patient.id, programs, zone, sessions)
    counted = {i.session.id for items in by_program.values() for i in items}
    loose = [s for s in sessions if s.status == "closed" and s.id not in counted]
    _fill(db, [i for items in by_program.values() for i in items])
    missed = no_session_flag(db, patient.id, programs, today, zone, settings)
    out = []
    for p in programs:
        items = by_program[p.id]
        flags = program_flags(p, items, today, settings)
        if missed is not None and store.is_active(p, today):
            flags.insert(0, missed.model_copy(update={"program_id": p.id}))
        out.append(ProgramProgress(
            program_id=p.id, name=p.name, active=store.is_active(p, today),
            version=p.versions[-1].number,
            sessions=[ProgramSessionOut(session_id=i.session.id, day=i.day,
                                        started_at=i.started_at, version=i.version.number,
                                        how=i.how) for i in items],
            weeks=weeks(p, items, today, zone),
            exercises=exercise_progress(p, items,
                                        lambda moment: targets_at(db, patient.id, moment)),
            pain=[PainPoint(session_id=i.session.id, day=i.day, started_at=i.started_at,
                            pain=i.pain, effort=i.effort)
                  for i in items if i.pain is not None or i.effort is not None],
            flags=flags, uncounted_sessions=_uncounted(p, loose, zone)))
    return out


def _uncounted(program: models.Program, loose: Sequence[models.Session],
               zone: ZoneInfo) -> int:
    """How many of the sessions no program counts (``loose``) started while ``program``
    ran: from its first version's first day (the clinic's) until it was ended."""
    first = program.versions[0].start_date
    return sum(1 for s in loose if local_day(s.started_at, zone) >= first
               and (program.ended_at is None
                    or aware(s.started_at) <= aware(program.ended_at)))
