"""The patient's data lifecycle and its trace: everything held about a patient as one
zip archive, and the audit log (``GET /api/audit``: an admin sees every entry, a
therapist the trail of their own patients and their own actions; JSON pages or CSV)."""

from __future__ import annotations

import csv
import io
import json
import zipfile
from datetime import UTC, date, datetime, time, timedelta
from typing import Annotated, BinaryIO, Literal

from armtrack.estimator.recording import write_recording_to
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response, StreamingResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import Select, or_, select
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..commands.output import write_angles_csv
from ..db import models
from ..programs import store
from ..reports import content
from ..reports.content import NoEstimates
from ..reports.targets import current_targets, patient_targets, target_history
from ..services import Services
from ..spreadsheet import spreadsheet_text
from ..store.processing import stored_estimates
from ..store.recordings import session_recording
from .deps import Db, Page, Therapist, in_export_turn, own_patient, services
from .schemas import DeviceOut, Id, PatientOut, QueryId
from .sessions import ANGLE_COLUMNS_END, session_out
from .spool import spooled

router = APIRouter(prefix="/api", tags=["lifecycle"], responses={
    401: {"description": "not signed in: a valid bearer token is required"}})


class AuditOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    at: datetime
    therapist_id: int | None
    device_id: int | None
    action: str
    patient_id: int | None
    session_id: int | None
    route: str
    client: str | None
    actor: str | None = Field(None, description="who, in words: the therapist's full name "
                              "and user name, or the kit's name (null: erased since)")


#: The CSV's columns: the log's own (ids only, no names).
AUDIT_FIELDS = [name for name in AuditOut.model_fields if name != "actor"]


def _json(value: object) -> str:
    return json.dumps(value, indent=2, default=str, ensure_ascii=False)


def _entries(patient_id: int) -> Select:
    return (select(models.AuditEntry).where(models.AuditEntry.patient_id == patient_id)
            .order_by(models.AuditEntry.id))


def _programs(db: DbSession, patient_id: int) -> list[dict]:
    """The patient's programs for their export: each with every version (its exercises)
    and the sessions that followed each version, oldest first."""
    targets = patient_targets(db, patient_id)
    out = []
    for program in db.scalars(select(models.Program).where(
            models.Program.patient_id == patient_id).order_by(models.Program.id)):
        followed = db.execute(
            select(models.SessionProgram.session_id, models.ProgramVersion.number)
            .join(models.ProgramVersion,
                  models.ProgramVersion.id == models.SessionProgram.version_id)
            .where(models.ProgramVersion.program_id == program.id)
            .order_by(models.SessionProgram.session_id)).all()
        out.append({
            "program": {"id": program.id, "name": program.name,
                        "created_at": program.created_at.isoformat(),
                        "ended_at": program.ended_at.isoformat() if program.ended_at
                        else None},
            "versions": [store.version_out(v, targets).model_dump(mode="json")
                         for v in program.versions],
            "sessions_followed": [{"session_id": s, "version": n} for s, n in followed]})
    return out


def _ratings(db: DbSession, session_id: int) -> list[dict]:
    """The pain (NRS 0–10) and effort (Borg CR10) the patient gave in a session, with
    their stream time [s] and when the server received them."""
    return [{"exercise": r.exercise, "t": r.t, "effort": r.effort, "pain": r.pain,
             "received_at": r.received_at.isoformat()}
            for r in db.scalars(select(models.SessionRating).where(
                models.SessionRating.session_id == session_id)
                .order_by(models.SessionRating.id))]


def patient_archive(db: DbSession, patient: models.Patient, out: BinaryIO) -> None:
    """Write to ``out`` (a seekable binary file) the zip of patient.json, devices.json (no
    tokens), targets.json, target_history.json (every setting and removal), programs.json
    (each program, every version with its exercises, and the sessions that followed each
    version), sessions.json, and per session ``sessions/<id>/recording.csv``,
    ``angles.csv`` and ``report.json`` (when estimated) and ``ratings.json`` (the pain and
    effort the patient gave, when any), and audit.json: every logged access to the
    patient's data. One session's data are in memory at a time; each file goes into the
    zip as it is made."""
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("patient.json", PatientOut.model_validate(patient).model_dump_json(
            indent=2))
        devices = db.scalars(select(models.Device).where(models.Device.patient_id == patient.id)
                             .order_by(models.Device.id))
        archive.writestr("devices.json", _json(
            [DeviceOut.model_validate(d).model_dump(mode="json") for d in devices]))
        targets = current_targets(db, patient.id)
        archive.writestr("targets.json", _json(
            [content.target_out(t).model_dump(mode="json") for t in targets.values()]))
        archive.writestr("target_history.json", _json(
            [{"angle": v.angle, "min_deg": v.min_deg, "max_deg": v.max_deg, "note": v.note,
              "set_at": v.set_at.isoformat(), "set_by": v.set_by}
             for v in target_history(db, patient.id)]))
        archive.writestr("programs.json", _json(_programs(db, patient.id)))
        sessions = list(db.scalars(select(models.Session)
                                   .where(models.Session.patient_id == patient.id)
                                   .order_by(models.Session.started_at, models.Session.id)))
        archive.writestr("sessions.json", _json(
            [session_out(s).model_dump(mode="json") for s in sessions]))
        for session in sessions:
            folder = f"sessions/{session.id}/"
            recording = session_recording(db, session)
            if recording.sensors:  # a session without samples has no recording file
                with archive.open(folder + "recording.csv", "w", force_zip64=True) as member:
                    write_recording_to(recording, member)
            del recording
            ratings = _ratings(db, session.id)
            if ratings:
                archive.writestr(folder + "ratings.json", _json(ratings))
            columns, values = stored_estimates(db, session)
            if columns:
                width = columns.index(ANGLE_COLUMNS_END) + 1
                with archive.open(folder + "angles.csv", "w", force_zip64=True) as member, \
                        io.TextIOWrapper(member, encoding="utf-8", newline="") as text:
                    write_angles_csv(text, columns[:width], values[:, :width])
                try:
                    report = content.session_report(db, session, current=targets, keep=False)
                    archive.writestr(folder + "report.json", report.model_dump_json(indent=2))
                except NoEstimates:
                    pass
        archive.writestr("audit.json", _json(
            [AuditOut.model_validate(e).model_dump(mode="json", exclude={"actor"})
             for e in db.scalars(_entries(patient.id))]))


@router.get("/patients/{patient_id}/export", response_class=Response, responses={
    200: {"content": {"application/zip": {}}, "description": "a zip archive"},
    404: {"description": "no such patient of this therapist's"}})
async def export_patient(patient_id: Id, therapist: Therapist, request: Request,
                         svc: Annotated[Services, Depends(services)]) -> StreamingResponse:
    """Everything held about the patient, as one zip archive: the patient, their kits
    (without tokens), targets, programs (every version, the sessions that followed each)
    and sessions as JSON, each session's raw data (``recording.csv``), angles
    (``angles.csv``), report (``report.json``) and the pain and effort given
    (``ratings.json``), and the audit log's entries about them."""
    def work(db: DbSession, therapist: models.Therapist) -> StreamingResponse:
        patient = own_patient(db, therapist, patient_id)
        # the zip goes to a temporary file (spool): the server's memory holds one
        # session's data at a time, whatever the patient's number of sessions
        return spooled(lambda out: patient_archive(db, patient, out), svc.settings.data_dir,
                       "application/zip", f"patient-{patient_id}.zip")
    return await in_export_turn(request, therapist, work)


def _audit_query(db: DbSession, therapist: models.Therapist, patient_id: int | None,
                 therapist_id: int | None, action: str | None,
                 since: datetime | None, before: datetime | None) -> Select:
    query = select(models.AuditEntry)
    if not therapist.is_admin:  # the trail of their patients, and what they did themselves
        theirs = select(models.Patient.id).where(models.Patient.therapist_id == therapist.id)
        query = query.where(or_(models.AuditEntry.patient_id.in_(theirs),
                                models.AuditEntry.therapist_id == therapist.id))
    if therapist_id is not None:
        query = query.where(models.AuditEntry.therapist_id == therapist_id)
    if patient_id is not None:
        query = query.where(models.AuditEntry.patient_id == patient_id)
    if action:
        query = query.where(models.AuditEntry.action == action)
    if since is not None:
        query = query.where(models.AuditEntry.at >= since)
    if before is not None:
        query = query.where(models.AuditEntry.at < before)
    return query.order_by(models.AuditEntry.id.desc())


def _day_start(day: date | None, svc: Services, days_after: int = 0) -> datetime | None:
    """Midnight starting ``day`` (+ ``days_after``) in the clinic's time zone, in UTC (as
    the log stores its moments: SQLite compares them as text); None for no bound."""
    if day is None:
        return None
    try:
        return datetime.combine(day + timedelta(days=days_after), time(0),
                                tzinfo=svc.settings.clinic_zone()).astimezone(UTC)
    except OverflowError:  # a bound beyond the dates there are (9999-12-31's end, year 1's
        return None        # start east of UTC) leaves nothing out: no bound (was a 500)


def _actors(db: DbSession, rows: list[models.AuditEntry]) -> list[AuditOut]:
    """The entries with who did each in words."""
    therapist_ids = {r.therapist_id for r in rows if r.therapist_id is not None}
    device_ids = {r.device_id for r in rows if r.device_id is not None}
    names: dict[tuple[str, int], str] = {}
    if therapist_ids:
        for t in db.scalars(select(models.Therapist)
                            .where(models.Therapist.id.in_(therapist_ids))):
            names["t", t.id] = f"{t.full_name} ({t.username})" if t.full_name else t.username
    if device_ids:
        for d in db.scalars(select(models.Device).where(models.Device.id.in_(device_ids))):
            names["d", d.id] = f"kit {d.name}"
    out = []
    for row in rows:
        actor = (names.get(("t", row.therapist_id)) if row.therapist_id is not None
                 else names.get(("d", row.device_id)) if row.device_id is not None else None)
        if actor is None and row.therapist_id is None and row.device_id is None:
            # the server's own actions: retention's erasures, a silent session's close
            actor = ("armtrack (kit silent)" if row.action == "closed_silence"
                     else f"{audit.CREATE_USER} (command line)"
                     if row.route.startswith(audit.CREATE_USER)
                     else "armtrack (retention)")
        out.append(AuditOut.model_validate(row).model_copy(update={"actor": actor}))
    return out


@router.get("/audit", response_model=list[AuditOut])
def list_audit(db: Db, therapist: Therapist, page: Annotated[Page, Depends()],
               svc: Annotated[Services, Depends(services)],
               patient_id: QueryId = None, therapist_id: QueryId = None,
               action: Annotated[str | None, Query(max_length=24)] = None,
               from_date: Annotated[date | None, Query(
                   description="entries from this day on (the clinic's calendar)")] = None,
               to_date: Annotated[date | None, Query(
                   description="entries up to the end of this day (the clinic's calendar)")]
               = None,
               format: Annotated[Literal["json", "csv"], Query()] = "json",
               ) -> list[AuditOut] | Response:
    """The audit log, newest first: who (a therapist or a device) viewed, exported,
    uploaded, erased … which patient's data, when, through which route, from which
    address. A clinic admin sees every entry; a therapist the trail of their own patients
    (whoever acted: they, a kit, an admin who reassigned them, a former therapist) and
    their own actions. Filters: ``patient_id``, ``therapist_id`` (the actor), ``action``,
    ``from_date``/``to_date`` (days of the clinic's time zone, both included).
    ``format=csv``: the matching entries as CSV (up to ``limit``)."""
    rows = list(db.scalars(_audit_query(db, therapist, patient_id, therapist_id, action,
                                        _day_start(from_date, svc),
                                        _day_start(to_date, svc, days_after=1))
                           .limit(page.limit).offset(page.offset)))
    if format == "json":
        return _actors(db, rows)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(AUDIT_FIELDS)
    for row in rows:
        writer.writerow([_csv_value(getattr(row, name)) for name in AUDIT_FIELDS])
    return Response(out.getvalue(), media_type="text/csv",
                    headers={"Content-Disposition": 'attachment; filename="audit.csv"'})


def _csv_value(value: object) -> object:
    if isinstance(value, datetime):
        return value.isoformat()
    return "" if value is None else spreadsheet_text(value)  # the client is anyone's text
