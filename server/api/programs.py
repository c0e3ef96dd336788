"""Exercise programs (``docs/programs.md``): the catalogue, a patient's programs and their
versions. A program is the patient's data: another therapist's is 404, as if it did not
exist."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, status
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from .. import audit, clock
from ..db import models
from ..programs import adherence, catalogue, store
from ..programs import fhir as program_fhir
from ..programs.calendar import clinic_zone, today
from ..programs.schemas import CatalogueOut, PrescriptionIn, ProgramIn, ProgramOut, VersionOut
from ..reports.targets import patient_targets
from ..services import Services
from ..settings import Settings
from .deps import Db, Held, Therapist, holds, own_patient, services
from .schemas import Id

router = APIRouter(prefix="/api", tags=["programs"], responses={
    401: {"description": "not signed in: a valid bearer token is required"},
    404: {"description": "no such patient or program of this therapist's"}})


def own_program(db: DbSession, therapist: models.Therapist, program_id: int
                ) -> models.Program:
    program = db.get(models.Program, program_id)
    if program is not None:
        patient = db.get(models.Patient, program.patient_id)
        if holds(therapist, patient):  # theirs, and not an admin's (docs/security.md)
            audit.note(patient_id=patient.id)
            return program
    raise HTTPException(status.HTTP_404_NOT_FOUND, f"no program {program_id}")


def settings_of(svc: Annotated[Services, Depends(services)]) -> Settings:
    return svc.settings


SettingsDep = Annotated[Settings, Depends(settings_of)]


def _out(db: DbSession, program: models.Program, settings: Settings) -> ProgramOut:
    return store.program_out(program, patient_targets(db, program.patient_id),
                             today(clinic_zone(settings.clinic_timezone)))


@router.get("/programs/catalogue", response_model=list[CatalogueOut])
def get_catalogue(therapist: Therapist, db: Db, patient_id: Annotated[int | None, Query(
        ge=1, le=2**31 - 1, description="say for each exercise whether this patient's kits "
        "measure it (measurable, why_not)")] = None) -> list[dict]:
    """The exercises a program can prescribe, each with the angle that measures it; with
    ``patient_id``, whether the patient's kits (the sensors their sessions streamed with)
    measure it, and why not."""
    entries = [e.as_dict() for e in catalogue.CATALOGUE.values()]
    if patient_id is None:
        return entries
    own_patient(db, therapist, patient_id)
    kits = store.patient_kits(db, patient_id)
    for entry, e in zip(entries, catalogue.CATALOGUE.values(), strict=True):
        if not kits:
            continue
        entry["measurable"] = any(catalogue.measurable(e, sensors) for _, sensors in kits)
        if not entry["measurable"]:
            worn = [s for s in catalogue.SEGMENT_WORDS  # chain order
                    if any(s in sensors for _, sensors in kits)]
            entry["why_not"] = catalogue.why_not(e, worn)
    return entries


@router.get("/patients/{patient_id}/programs", response_model=list[ProgramOut])
def list_programs(patient_id: Id, db: Db, therapist: Therapist,
                  settings: SettingsDep) -> list[ProgramOut]:
    """The patient's programs, oldest first, each with its current version."""
    own_patient(db, therapist, patient_id)
    return [_out(db, p, settings) for p in store.patient_programs(db, patient_id)]


@router.post("/patients/{patient_id}/programs", response_model=ProgramOut,
             status_code=status.HTTP_201_CREATED,
             responses={409: {"description": "the patient has a program of that name"}})
def create_program(patient_id: Id, body: ProgramIn, db: Db, therapist: Therapist,
                   settings: SettingsDep) -> ProgramOut:
    """Prescribe a program: its version 1."""
    own_patient(db, therapist, patient_id)
    try:
        program = store.create_program(db, patient_id, body, therapist.id)
    except store.ProgramConflict as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    return _out(db, program, settings)


@router.get("/programs/{program_id}", response_model=ProgramOut)
def get_program(program_id: Id, db: Db, therapist: Therapist,
                settings: SettingsDep) -> ProgramOut:
    """The program with its current version."""
    return _out(db, own_program(db, therapist, program_id), settings)


@router.put("/programs/{program_id}", response_model=ProgramOut)
def change_program(program_id: Id, body: PrescriptionIn, db: Db, therapist: Therapist,
                   settings: SettingsDep) -> ProgramOut:
    """Change the prescription: saved as the program's next version (the sessions that
    followed earlier versions keep them). An ended program is in force again."""
    program = own_program(db, therapist, program_id)
    store.change_program(db, program, body, therapist.id)
    return _out(db, program, settings)


@router.get("/programs/{program_id}/versions", response_model=list[VersionOut])
def list_versions(program_id: Id, db: Db, therapist: Therapist) -> list[VersionOut]:
    """Every version of the program, oldest first."""
    program = own_program(db, therapist, program_id)
    targets = patient_targets(db, program.patient_id)
    return [store.version_out(v, targets) for v in program.versions]


@router.post("/programs/{program_id}/end", response_model=ProgramOut)
def end_program(program_id: Id, db: Db, therapist: Therapist,
                settings: SettingsDep) -> ProgramOut:
    """End the program now: no more prescriptions or flags after today; its history
    stays."""
    program = own_program(db, therapist, program_id)
    store.end_program(db, program)
    return _out(db, program, settings)


@router.get("/programs/{program_id}/adherence", response_model=adherence.ProgramProgress)
def get_adherence(program_id: Id, db: Db, therapist: Therapist, right: Held,
                  settings: SettingsDep) -> adherence.ProgramProgress:
    """The program's sessions, per ISO week prescribed vs done, per exercise the range
    over time against its target, pain over time, and its flags (``docs/programs.md``)."""
    program = own_program(db, therapist, program_id)
    patient = db.get(models.Patient, program.patient_id)
    return right.held(next(p for p in adherence.patient_programs_progress(db, patient, settings)
                           if p.program_id == program.id))


class PatientFlags(BaseModel):
    patient_id: int
    flags: list[adherence.Flag]


@router.get("/flags", response_model=list[PatientFlags])
def get_flags(db: Db, therapist: Therapist, right: Held,
              settings: SettingsDep) -> list[PatientFlags]:
    """The therapist's patients who need a look (``docs/programs.md``, "Flags"): no
    session for days, range falling, pain rising. Patients without a flag are left out,
    and discharged ones (docs/extensions/discharge.md: no session is expected of them).
    A clinic admin holds no patients (docs/security.md), whatever the database says."""
    if therapist.is_admin:
        return []
    patients = list(db.scalars(select(models.Patient.id).where(
        models.Patient.therapist_id == therapist.id, models.Patient.discharged_is(False))
        .order_by(models.Patient.id)))
    found = adherence.flags_by_patient(db, patients, settings)
    # read again as the answer goes: a patient reassigned or erased meanwhile is left out
    theirs = right.theirs(found)
    return [PatientFlags(patient_id=p, flags=found[p]) for p in patients if p in theirs]


@router.get("/programs/{program_id}/careplan.fhir.json", response_class=JSONResponse,
            responses={200: {"content": {"application/fhir+json": {"schema": {
                "type": "object", "description": "a FHIR R4 Bundle"}}},
                "description": "FHIR R4 Bundle"}})
def get_careplan_fhir(program_id: Id, db: Db, therapist: Therapist, right: Held,
                      settings: SettingsDep) -> JSONResponse:
    """The program as FHIR R4: CarePlan with its activities, a Goal and a ServiceRequest
    per exercise, and the sessions' range-of-motion, pain and effort Observations
    (LOINC where it has a fitting term, SNOMED CT otherwise; docs/programs.md)."""
    program = own_program(db, therapist, program_id)
    if not program.versions:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no program {program_id}")
    patient = db.get(models.Patient, program.patient_id)
    zone = clinic_zone(settings.clinic_timezone)
    sessions = adherence.filled_sessions(db, patient.id, program, zone)
    bundle = program_fhir.careplan_bundle(program, patient, patient_targets(db, patient.id),
                                          sessions, today(zone), clock.now())
    return right.held(JSONResponse(bundle, media_type="application/fhir+json", headers={
        "Content-Disposition": f'attachment; filename="program-{program_id}.fhir.json"'}))


@router.get("/patients/{patient_id}/progress.pdf", response_class=Response,
            responses={200: {"content": {"application/pdf": {}}, "description": "PDF"}})
def get_progress_pdf(patient_id: Id, db: Db, therapist: Therapist, right: Held,
                     settings: SettingsDep) -> Response:
    """The patient's programs as a PDF: per program the flags, adherence per ISO week,
    the range of each exercise against its target, pain and effort over time."""
    patient = own_patient(db, therapist, patient_id)
    programs = adherence.patient_programs_progress(db, patient, settings)
    zone = clinic_zone(settings.clinic_timezone)
    from ..programs import pdf as program_pdf  # here: matplotlib is slow to import

    data = program_pdf.progress_pdf(patient, programs, today(zone), settings.clinic_timezone,
                                    clinic_name=settings.clinic_name,
                                    therapist=therapist.full_name or therapist.username)
    return right.held(Response(data, media_type="application/pdf", headers={
        "Content-Disposition": f'attachment; filename="patient-{patient_id}-progress.pdf"'}))
