"""Patients and their devices (sensor kits and their tokens)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request, status
from sqlalchemy import func, select

from ..auth import new_token
from ..db import models
from ..kit.link import kit_url, qr_svg_data_uri, secure_enough
from ..services import Services
from ..store.gyro_bias import forget_kit
from .deps import Db, Page, Therapist, own_device, own_patient, services
from .erase import erase_patient
from .schemas import (
    DeviceCreated,
    DeviceIn,
    DeviceOut,
    Id,
    PatientIn,
    PatientOut,
    PatientUpdate,
)

router = APIRouter(prefix="/api", tags=["patients"])


@router.post("/patients", response_model=PatientOut, status_code=status.HTTP_201_CREATED)
def create_patient(body: PatientIn, db: Db, therapist: Therapist) -> models.Patient:
    """A new patient of the signed-in therapist (not of a clinic admin: admins hold no
    patients)."""
    if therapist.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "a clinic admin holds no patients: "
                            "sign in with a therapist's account to add one")
    patient = models.Patient(therapist_id=therapist.id, **body.model_dump())
    db.add(patient)
    db.commit()
    return patient


@router.get("/patients", response_model=list[PatientOut])
def list_patients(db: Db, therapist: Therapist, page: Annotated[Page, Depends()],
                  q: str | None = None, discharged: bool | None = None) -> list[PatientOut]:
    """The therapist's patients by name, each with when their latest session started;
    ``q`` keeps those whose name contains it (a clinic admin holds none:
    ``/api/admin/patients`` lists everyone's). Extension (docs/extensions/discharge.md):
    ``discharged=false`` keeps the patients in care, ``true`` the discharged ones; without
    it, every patient, as before."""
    if therapist.is_admin:
        return []
    last = (select(models.Session.patient_id,
                   func.max(models.Session.started_at).label("last"))
            .group_by(models.Session.patient_id).subquery())
    query = (select(models.Patient, last.c.last)
             .outerjoin(last, last.c.patient_id == models.Patient.id)
             .where(models.Patient.therapist_id == therapist.id))
    if q:
        query = query.where(models.Patient.name.icontains(q, autoescape=True))
    if discharged is not None:
        query = query.where(models.Patient.discharged_is(discharged))
    rows = db.execute(query.order_by(models.Patient.name, models.Patient.id)
                      .limit(page.limit).offset(page.offset)).all()
    return [PatientOut.model_validate(patient).model_copy(
                update={"last_session_at": _aware(at)}) for patient, at in rows]


def _aware(moment):
    """An aggregate's datetime comes back without the column's type: naive on SQLite."""
    if moment is None or getattr(moment, "tzinfo", None) is not None:
        return moment
    if isinstance(moment, str):  # SQLite's max() of a DATETIME column is its text
        moment = datetime.fromisoformat(moment)
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


@router.patch("/patients/{patient_id}", response_model=PatientOut)
def update_patient(patient_id: Id, body: PatientUpdate, db: Db,
                   therapist: Therapist) -> models.Patient:
    """Change a patient's record: name, side, height, clinic number, date of birth (the
    fields given; ``null`` clears the clinic number or date of birth). Sessions already
    recorded keep the side and height they were estimated with."""
    patient = own_patient(db, therapist, patient_id)
    changes = body.model_dump(exclude_unset=True)
    for required in ("name", "side", "height_m"):
        if required in changes and changes[required] is None:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_ENTITY,
                                f"{required} cannot be cleared, only changed")
    for key, value in changes.items():
        setattr(patient, key, value)
    db.commit()
    return patient


@router.get("/patients/{patient_id}", response_model=PatientOut)
def get_patient(patient_id: Id, db: Db, therapist: Therapist) -> models.Patient:
    return own_patient(db, therapist, patient_id)


@router.post("/patients/{patient_id}/discharge", response_model=PatientOut)
def discharge_patient(patient_id: Id, db: Db, therapist: Therapist) -> models.Patient:
    """Discharge the patient (docs/extensions/discharge.md): every session, report and
    program stays; their kits start no new session (a stream under way goes on) until
    readmitted. Again on a discharged patient: the first date stays."""
    patient = own_patient(db, therapist, patient_id)
    if patient.discharged_at is None:
        patient.discharged_at = datetime.now(UTC)
        db.commit()
    return patient


@router.post("/patients/{patient_id}/readmit", response_model=PatientOut)
def readmit_patient(patient_id: Id, db: Db, therapist: Therapist) -> models.Patient:
    """Take a discharged patient back into care: their kits start sessions again."""
    patient = own_patient(db, therapist, patient_id)
    if patient.discharged_at is not None:
        patient.discharged_at = None
        db.commit()
    return patient


@router.delete("/patients/{patient_id}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_patient(patient_id: Id, therapist: Therapist,
                         svc: Annotated[Services, Depends(services)]) -> None:
    """Erase the patient with all their sessions, data and devices; their kits' streams,
    live feeds and 3D views close."""
    device_ids = await svc.run_db(_patient_devices, therapist, patient_id)
    for device_id in device_ids:
        await svc.revoke_device(device_id)
    await svc.run_db(erase_patient, patient_id)
    svc.hub.forget_patient(patient_id)
    await svc.access.recheck()


def _patient_devices(db, therapist, patient_id: int) -> list[int]:
    own_patient(db, therapist, patient_id)
    return list(db.scalars(select(models.Device.id)
                           .where(models.Device.patient_id == patient_id)))


@router.post("/patients/{patient_id}/devices", response_model=DeviceCreated,
             status_code=status.HTTP_201_CREATED)
def create_device(patient_id: Id, body: DeviceIn, db: Db, therapist: Therapist,
                  request: Request) -> dict:
    """A new sensor kit for the patient; its token is in this answer only, with the phone
    kit's link (the token in its fragment) and its QR code."""
    own_patient(db, therapist, patient_id)
    token, digest = new_token("dev_")
    device = models.Device(patient_id=patient_id, name=body.name, token_hash=digest)
    db.add(device)
    db.commit()
    base = (request.app.state.services.settings.public_url
            or str(request.base_url).rstrip("/"))
    url = kit_url(base, token)
    return {**DeviceOut.model_validate(device).model_dump(), "token": token,
            "kit_url": url, "kit_qr": qr_svg_data_uri(url),
            "kit_url_secure": secure_enough(base)}


@router.get("/patients/{patient_id}/devices", response_model=list[DeviceOut])
def list_devices(patient_id: Id, db: Db, therapist: Therapist,
                 page: Annotated[Page, Depends()]) -> list[DeviceOut]:
    """The patient's kits, oldest first, each with when its newest session started."""
    own_patient(db, therapist, patient_id)
    last = (select(models.Session.device_id, func.max(models.Session.started_at).label("at"))
            .where(models.Session.patient_id == patient_id)
            .group_by(models.Session.device_id).subquery())
    rows = db.execute(select(models.Device, last.c.at)
                      .outerjoin(last, last.c.device_id == models.Device.id)
                      .where(models.Device.patient_id == patient_id)
                      .order_by(models.Device.id).limit(page.limit).offset(page.offset)).all()
    return [DeviceOut.model_validate(device).model_copy(update={"last_session_at": at})
            for device, at in rows]


@router.delete("/devices/{device_id}", status_code=status.HTTP_204_NO_CONTENT)
async def revoke_device(device_id: Id, therapist: Therapist,
                        svc: Annotated[Services, Depends(services)]) -> None:
    """Revoke a device: its token stops working at once; open streams close with 4401."""
    await svc.run_db(_revoke, therapist, device_id)
    await svc.revoke_device(device_id)


def _revoke(db, therapist, device_id: int) -> None:
    device = own_device(db, therapist, device_id)
    if device.revoked_at is None:
        device.revoked_at = datetime.now(UTC)
        forget_kit(db, device.id)  # its sensors' biases go with it (docs/gyro-bias-memory.md)
        db.commit()

