"""Progress: the same metrics across a patient's sessions, oldest first, as a table and a
trend per angle.

Per session: the ``rom`` of its report (against the patient's targets in force when it
started), the repetitions per angle, the median SPARC and the largest peak angular
velocity per angle (kept per session once read: :func:`session_row`).
Per angle, the trend over the sessions where it moved: first and last range, their
difference, and the least-squares slope of the range against the session's start time in
degrees per week (``None`` unless the sessions span at least a day: a slope over minutes
means nothing clinically).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from datetime import datetime

import numpy as np
from pydantic import BaseModel, Field
from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..lru import BoundedLru
from ..programs.adherence import ProgramProgress
from ..programs.stream import session_targets, sessions_targets, with_band_done
from ..spreadsheet import spreadsheet_text
from .content import (
    AngleName,
    NoEstimates,
    RomEntry,
    SessionReport,
    TargetOut,
    finite,
    report_key,
    rom_against,
    session_report,
    utc,
)
from .targets import Target

SECONDS_PER_WEEK = 7 * 24 * 3600.0
#: A slope needs sessions spread over at least this [s]: one day.
MIN_TREND_SPAN_S = 24 * 3600.0


class SessionProgress(BaseModel):
    session_id: int
    started_at: datetime
    status: str
    processed: bool = Field(description="estimates exist, so the metrics below do")
    processing_error: str | None
    rom: dict[AngleName, RomEntry]
    repetitions: dict[AngleName, int]
    median_sparc: dict[AngleName, float | None]
    peak_velocity_deg_s: dict[AngleName, float | None]


class Trend(BaseModel):
    angle: AngleName
    sessions: int
    first_range: float
    last_range: float
    change_deg: float = Field(description="last − first range [deg]")
    slope_deg_per_week: float | None
    last_percent_of_normal: float | None
    last_percent_of_target: float | None
    last_target_reached: bool | None


class Progress(BaseModel):
    patient_id: int
    patient_name: str
    side: str
    targets: list[TargetOut]
    sessions: list[SessionProgress] = Field(description="oldest first")
    trend: dict[AngleName, Trend]
    programs: list[ProgramProgress] = Field(
        default_factory=list, description="the patient's exercise programs: adherence per "
        "ISO week, range per exercise against its target, pain, flags (docs/programs.md)")


def session_progress(session: models.Session, report: SessionReport | None) -> SessionProgress:
    reps: dict[str, int] = {}
    sparc: dict[str, list[float]] = {}
    velocity: dict[str, float | None] = {}
    for exercise in report.exercises if report else []:
        for a in exercise.angles:
            reps[a.angle] = reps.get(a.angle, 0) + a.repetitions
            sparc.setdefault(a.angle, []).extend(d.sparc for d in a.details
                                                 if d.sparc is not None)
            if a.peak_velocity_deg_s is not None:
                velocity[a.angle] = max(velocity.get(a.angle) or 0.0, a.peak_velocity_deg_s)
    return SessionProgress(
        session_id=session.id, started_at=utc(session.started_at), status=session.status,
        processed=report is not None, processing_error=session.processing_error,
        rom=dict(report.rom) if report else {}, repetitions=reps,
        median_sparc={k: finite(float(np.median(v))) if v else None for k, v in sparc.items()},
        peak_velocity_deg_s=velocity)


def trend(rows: Sequence[SessionProgress]) -> dict[str, Trend]:
    out = {}
    angles = dict.fromkeys(a for r in rows for a in r.rom)
    for angle in angles:
        points = [(r.started_at.timestamp(), r.rom[angle]) for r in rows if angle in r.rom]
        times = np.array([p[0] for p in points])
        ranges = np.array([p[1].range for p in points])
        slope = None
        if len(points) > 1 and np.ptp(times) >= MIN_TREND_SPAN_S:
            slope = finite(float(np.polyfit(times, ranges, 1)[0]) * SECONDS_PER_WEEK, 2)
        last = points[-1][1]
        out[angle] = Trend(angle=angle, sessions=len(points), first_range=points[0][1].range,
                           last_range=last.range,
                           change_deg=finite(last.range - points[0][1].range, 2),
                           slope_deg_per_week=slope,
                           last_percent_of_normal=last.percent_of_normal,
                           last_percent_of_target=last.percent_of_target,
                           last_target_reached=last.target_reached)
    return out


#: Sessions' progress rows without targets, as JSON, with the names of the exercises the
#: session did, by what identifies their estimates (the report cache's key: a new
#: estimate, reprocessing, a resumed stream make a new key), so that a patient's progress
#: needs no report built again once read, past the report cache's 64 sessions. A row with
#: 10 angles: 3.7 kB of JSON (17 kB as objects), its key 0.6 kB; 10,000 rows ≈ 45 MB at
#: most.
_ROWS: BoundedLru[tuple, tuple[bytes, tuple[str, ...]]] = BoundedLru(10_000)

Judged = tuple[Mapping[str, Target], Mapping[str, tuple[str, Target | None]]]


def session_row(db: DbSession, session: models.Session,
                judged: Judged | None = None) -> SessionProgress:
    """The session's progress row, against what it is judged by (``judged``: its
    ``session_targets``, read now when not given; only the row without targets is kept).
    An angle that two exercises of the followed version give different bands (no one
    "Target then") takes the band of the one the session did when it did only one."""
    key = report_key(session)
    kept = _ROWS.get(key)
    if kept is not None:
        row, done = SessionProgress.model_validate_json(kept[0]), kept[1]
    else:
        try:  # one pass over many sessions: the reports are not kept, their rows are
            report = session_report(db, session, {}, current={}, keep=False)
        except NoEstimates:  # nothing kept: its estimates may come at any moment
            return session_progress(session, None)
        row = session_progress(session, report)
        done = tuple(e.name for e in report.exercises)
        _ROWS.put(key, (row.model_dump_json().encode(), done))
    targets, bands = judged if judged is not None else session_targets(db, session)
    targets = with_band_done(dict(targets), dict(bands), done)
    return row.model_copy(update={"rom": rom_against(row.rom, targets),
                                  "processing_error": session.processing_error})


def session_rows(db: DbSession, patient_id: int, sessions: Sequence[models.Session]
                 ) -> list[SessionProgress]:
    """``session_row`` of each of a patient's sessions, their targets read in a few
    queries for all (``programs.stream.sessions_targets``)."""
    judged = sessions_targets(db, patient_id, sessions)
    return [session_row(db, s, judged[s.id]) for s in sessions]


def progress(patient: models.Patient, rows: Sequence[SessionProgress],
             targets: Sequence[TargetOut]) -> Progress:
    """``rows``: each session's (:func:`session_row`), oldest first."""
    return Progress(patient_id=patient.id, patient_name=patient.name, side=patient.side,
                    targets=list(targets), sessions=rows,
                    trend=trend([r for r in rows if r.processed]))


PROGRESS_COLUMNS = ("session_id", "started_at", "status", "angle", "min", "max", "range",
                    "percent_of_normal", "target_min", "target_max", "percent_of_target",
                    "target_reached", "repetitions", "median_sparc", "peak_velocity_deg_s")


def progress_csv(p: Progress) -> str:
    """One row per session and angle that moved (a session without estimates: one row
    with its status only)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(PROGRESS_COLUMNS)
    for s in p.sessions:
        if not s.rom:
            writer.writerow([s.session_id, s.started_at.isoformat(), s.status,
                             *[""] * (len(PROGRESS_COLUMNS) - 3)])
        for angle, rom in s.rom.items():
            values = [rom.min, rom.max, rom.range, rom.percent_of_normal, rom.target_min,
                      rom.target_max, rom.percent_of_target, rom.target_reached,
                      s.repetitions.get(angle, 0), s.median_sparc.get(angle),
                      s.peak_velocity_deg_s.get(angle)]
            writer.writerow([s.session_id, s.started_at.isoformat(), spreadsheet_text(s.status),
                             spreadsheet_text(angle),
                             *("" if v is None else ("yes" if v is True else "no")
                               if isinstance(v, bool) else v for v in values)])
    return out.getvalue()
