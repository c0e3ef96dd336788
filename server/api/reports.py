"""Session reports and exports (JSON, CSV, PDF, OpenSim ``.mot`` / ``.sto``, FHIR R4), a
patient's progress across sessions, and the therapist's targets per joint
(``armtrack.server.reports``)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Request, status
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..programs.adherence import patient_programs_progress
from ..programs.stream import followed_version
from ..reports import content, fhir, opensim
from ..reports import csv as report_csv
from ..reports import progress as progress_mod
from ..reports.content import AngleName, NoEstimates, SessionReport, TargetOut
from ..reports.targets import (
    TargetIn,
    current_targets,
    delete_target,
    set_target,
    target_history,
)
from ..services import Services
from ..settings import Settings
from ..store.recordings import dated_by
from .deps import Db, Held, Therapist, in_export_turn, own_patient, own_session, services
from .spool import as_text, spooled

router = APIRouter(prefix="/api", tags=["reports"], responses={
    400: {"description": "the body is not JSON"},
    401: {"description": "not signed in: a valid bearer token is required"},
    404: {"description": "no such session or patient of this therapist's"}})

#: Row ids fit a 32-bit integer on every database the server runs on.
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]

CSV = {200: {"content": {"text/csv": {}}, "description": "CSV"}}
TEXT = {200: {"content": {"text/plain": {}}, "description": "text"}}
CONFLICT = {409: {"description": "the session has no estimates yet"}}


def _report(db: DbSession, therapist: models.Therapist, session_id: int
            ) -> tuple[models.Session, SessionReport]:
    session = own_session(db, therapist, session_id)
    try:
        return session, content.session_report(db, session)
    except NoEstimates as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None


def _data(db: DbSession, therapist: models.Therapist, session_id: int) -> content.SessionData:
    session = own_session(db, therapist, session_id)
    try:
        return content.load_session(db, session)
    except NoEstimates as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None


def _attachment(body: str | bytes, media_type: str, filename: str) -> Response:
    return Response(body, media_type=media_type,
                    headers={"Content-Disposition": f'attachment; filename="{filename}"'})


@router.get("/sessions/{session_id}/report", response_model=SessionReport,
            responses=CONFLICT)
def get_report(session_id: Id, db: Db, therapist: Therapist, right: Held) -> SessionReport:
    """The session's report: range of motion per angle that moved (calibration poses
    excluded) against normal values and the patient's targets, exercises with repetitions,
    movement times, peak velocities, smoothness and consistency, and data quality."""
    return right.held(_report(db, therapist, session_id)[1])


@router.get("/sessions/{session_id}/report.csv", response_class=Response,
            responses={**CSV, **CONFLICT})
def get_report_csv(session_id: Id, db: Db, therapist: Therapist, right: Held) -> Response:
    """The report's summary as CSV: one row per angle, for the session and per exercise.
    (Per-sample angles: ``/api/sessions/{id}/angles.csv``.)"""
    _, report = _report(db, therapist, session_id)
    return right.held(_attachment(report_csv.report_csv(report), "text/csv",
                                  f"session-{session_id}-report.csv"))


@router.get("/sessions/{session_id}/report.pdf", response_class=Response,
            responses={200: {"content": {"application/pdf": {}}, "description": "PDF"},
                       **CONFLICT})
async def get_report_pdf(session_id: Id, therapist: Therapist, request: Request,
                         svc: Annotated[Services, Depends(services)]) -> Response:
    """The report as a PDF a clinic files or sends: a one-page summary (clinic,
    therapist, patient identifiers, local date and time, what was done, range against
    normal, the target then, the previous sessions and the change, a plain sentence),
    then the details and a technical appendix (four pages)."""
    return await in_export_turn(request, therapist, _report_pdf, session_id, svc.settings)


def _report_pdf(db: DbSession, therapist: models.Therapist, session_id: int,
                settings: Settings) -> Response:
    session = own_session(db, therapist, session_id)
    try:
        data = content.load_session(db, session)
    except NoEstimates as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    from ..reports import pdf  # here: matplotlib takes ~0.5 s to import (server start)
    from ..reports.pdf_summary import Letterhead

    report = content.session_report(db, session, data=data)
    patient = data.patient
    letterhead = Letterhead(
        clinic_name=settings.clinic_name, clinic_address=settings.clinic_address,
        zone=settings.clinic_zone(), therapist=therapist.full_name or therapist.username,
        clinic_number=patient.clinic_number, date_of_birth=patient.date_of_birth,
        dated=dated_by(session), clock=settings.clinic_clock,
        program=program_words(followed_version(db, session.id)),
        unfinished=_unfinished_sets(db, session))
    return _attachment(pdf.report_pdf(report, data, letterhead,
                                      _previous(db, session, PREVIOUS_IN_PDF)),
                       "application/pdf", f"session-{session_id}-report.pdf")


def _unfinished_sets(db: DbSession, session: models.Session
                    ) -> tuple[tuple[str, float, int | None, int | None], ...]:
    """The sets the session page says the patient left part way ("stopped after 0 of
    10"), for the PDF to say them alike: (name, start_s, repetitions, asked)."""
    from .session_summary import summarise

    return tuple((e["name"], float(e["start"]), e.get("repetitions"), e.get("asked"))
                 for e in summarise(db, session)["exercises"] if e.get("unfinished"))


def program_words(version: models.ProgramVersion | None) -> str | None:
    """"Elbow at home, version 2": the program a session followed, as the PDF names it."""
    return None if version is None else f"{version.program.name}, version {version.number}"


#: Earlier sessions the PDF's summary compares with.
PREVIOUS_IN_PDF = 3


def _previous(db: DbSession, session: models.Session, count: int
              ) -> list[tuple[datetime, SessionReport]]:
    """The patient's ``count`` latest estimated sessions before ``session``: (start,
    report), newest first."""
    earlier = db.scalars(select(models.Session).where(
        models.Session.patient_id == session.patient_id, models.Session.id != session.id,
        models.Session.started_at < session.started_at)
        .order_by(models.Session.started_at.desc()).limit(count * 2))
    out = []
    for other in earlier:
        try:
            out.append((other.started_at, content.session_report(db, other)))
        except NoEstimates:
            continue
        if len(out) == count:
            break
    return out


@router.get("/sessions/{session_id}/report.mot", response_class=Response,
            responses={**TEXT, **CONFLICT})
async def get_report_mot(session_id: Id, therapist: Therapist, request: Request,
                         svc: Annotated[Services, Depends(services)]) -> Response:
    """Joint angles as an OpenSim motion file with the Rajagopal model's coordinates
    (``arm_flex_r``, ``arm_add_r`` positive in adduction, ``arm_rot_r``,
    ``elbow_flex_r``, ``pro_sup_r``, ``wrist_flex_r``, ``wrist_dev_r``; ``_l`` on the
    left), in degrees."""
    def work(db: DbSession, therapist: models.Therapist) -> Response:
        data = _data(db, therapist, session_id)
        return spooled(as_text(lambda out: opensim.write_mot(
            out, data, f"armtrack session {session_id}")), svc.settings.data_dir,
            "text/plain", f"session-{session_id}.mot")
    return await in_export_turn(request, therapist, work)


@router.get("/sessions/{session_id}/report.sto", response_class=Response,
            responses={**TEXT, **CONFLICT})
async def get_report_sto(session_id: Id, therapist: Therapist, request: Request,
                         svc: Annotated[Services, Depends(services)]) -> Response:
    """Segment orientations as an OpenSense quaternion table (``<body>_imu`` columns)."""
    def work(db: DbSession, therapist: models.Therapist) -> Response:
        data = _data(db, therapist, session_id)
        return spooled(as_text(lambda out: opensim.write_sto(out, data)),
                       svc.settings.data_dir, "text/plain", f"session-{session_id}.sto")
    return await in_export_turn(request, therapist, work)


@router.get("/sessions/{session_id}/report.fhir.json", response_class=JSONResponse,
            responses={200: {"content": {"application/fhir+json": {"schema": {
                "type": "object", "description": "a FHIR R4 Bundle"}}},
                "description": "FHIR R4 Bundle"}, **CONFLICT})
def get_report_fhir(session_id: Id, db: Db, therapist: Therapist, right: Held
                    ) -> JSONResponse:
    """The ranges of motion as FHIR R4 Observations (SNOMED CT 364564000) grouped in a
    DiagnosticReport, in a collection Bundle."""
    _, report = _report(db, therapist, session_id)
    return right.held(JSONResponse(fhir.fhir_bundle(report), media_type="application/fhir+json",
                        headers={"Content-Disposition":
                                 f'attachment; filename="session-{session_id}.fhir.json"'}))


def _progress(db: DbSession, therapist: models.Therapist, patient_id: int
              ) -> progress_mod.Progress:
    patient = own_patient(db, therapist, patient_id)
    targets = current_targets(db, patient_id)
    sessions = list(db.scalars(select(models.Session)
                               .where(models.Session.patient_id == patient_id)
                               .order_by(models.Session.started_at, models.Session.id)))
    # each session against the targets in force at its time; today's beside
    return progress_mod.progress(patient, progress_mod.session_rows(db, patient_id, sessions),
                                 [content.target_out(t) for t in targets.values()])


@router.get("/patients/{patient_id}/progress", response_model=progress_mod.Progress)
def get_progress(patient_id: Id, db: Db, therapist: Therapist, right: Held,
                 svc: Annotated[Services, Depends(services)]) -> progress_mod.Progress:
    """The report's metrics for each of the patient's sessions, oldest first, against the
    patient's targets, and per angle the trend (change and slope per week of the range);
    the patient's programs with their adherence (``docs/programs.md``)."""
    result = _progress(db, therapist, patient_id)
    result.programs = patient_programs_progress(db, db.get(models.Patient, patient_id),
                                                svc.settings)
    return right.held(result)


@router.get("/patients/{patient_id}/progress.csv", response_class=Response, responses=CSV)
def get_progress_csv(patient_id: Id, db: Db, therapist: Therapist, right: Held) -> Response:
    """Progress as CSV: one row per session and angle."""
    return right.held(_attachment(
        progress_mod.progress_csv(_progress(db, therapist, patient_id)),
        "text/csv", f"patient-{patient_id}-progress.csv"))


@router.get("/patients/{patient_id}/targets", response_model=list[TargetOut])
def get_targets(patient_id: Id, db: Db, therapist: Therapist) -> list[TargetOut]:
    """The patient's target range per angle [deg]."""
    own_patient(db, therapist, patient_id)
    return [content.target_out(t) for t in current_targets(db, patient_id).values()]


class TargetVersionOut(BaseModel):
    """One setting (or, with ``min_deg`` and ``max_deg`` null, removal) of a target."""

    angle: AngleName
    min_deg: float | None
    max_deg: float | None
    note: str | None
    set_at: datetime
    set_by: int | None = Field(description="the therapist who set it")


@router.get("/patients/{patient_id}/targets/history", response_model=list[TargetVersionOut])
def get_target_history(patient_id: Id, db: Db, therapist: Therapist
                       ) -> list[TargetVersionOut]:
    """Every setting and removal of the patient's targets, oldest first: a session's
    report compares it with the targets in force when it started."""
    own_patient(db, therapist, patient_id)
    return [TargetVersionOut(angle=v.angle, min_deg=v.min_deg, max_deg=v.max_deg,
                             note=v.note, set_at=v.set_at, set_by=v.set_by)
            for v in target_history(db, patient_id)]


@router.put("/patients/{patient_id}/targets/{angle}", response_model=TargetOut)
def put_target(patient_id: Id, angle: AngleName, body: TargetIn, db: Db,
               therapist: Therapist) -> TargetOut:
    """Set (or replace) the patient's target range for one angle [deg], in the signs of
    ``docs/spec/kinematics.md``."""
    own_patient(db, therapist, patient_id)
    set_target(db, patient_id, angle, body, set_by=therapist.id)
    return content.target_out(current_targets(db, patient_id)[angle])


@router.delete("/patients/{patient_id}/targets/{angle}",
               status_code=status.HTTP_204_NO_CONTENT)
def remove_target(patient_id: Id, angle: AngleName, db: Db, therapist: Therapist) -> None:
    """Remove the patient's target for one angle."""
    own_patient(db, therapist, patient_id)
    if not delete_target(db, patient_id, angle, set_by=therapist.id):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"patient {patient_id} has no target for {angle}")
