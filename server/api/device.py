"""Device-scoped reads (``docs/extensions/device-today.md``): what a kit may ask with its
own device token (``Authorization: Bearer <token>``), about its own patient only. No
therapist route accepts a device token, and these answer nothing about other patients."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..auth import hash_token
from ..db import models
from ..programs.calendar import today as clinic_today
from ..programs.recent import recent_sessions
from ..programs.today import todays_exercises
from .deps import Db, oauth2, unauthorized

router = APIRouter(prefix="/api/device", tags=["device"])


def current_device(db: Db, token: Annotated[str | None, Depends(oauth2)]) -> models.Device:
    """The device of a valid, unrevoked device token (401 otherwise)."""
    if not token:
        raise unauthorized("a device token is required: Authorization: Bearer <token>")
    device = _device_of_token(db, token)
    if device is None:
        raise unauthorized("the device token is unknown or was revoked: ask your "
                           "therapist for a new link")
    audit.note(device_id=device.id, patient_id=device.patient_id)
    return device


def _device_of_token(db: DbSession, token: str) -> models.Device | None:
    return db.scalar(select(models.Device).where(
        models.Device.token_hash == hash_token(token), models.Device.revoked_at.is_(None)))


Device = Annotated[models.Device, Depends(current_device)]


@router.get("/today")
def today(request: Request, db: Db, device: Device) -> dict[str, Any]:
    """Today's exercises for this device's patient, with their target bands, for a phone
    on either segment (each exercise names its ``sensor``): the program in force today
    (the clinic's day) with its dose and version, else the default session; ``discharged``:
    the therapist discharged the patient, the kit starts no new session
    (docs/extensions/discharge.md); ``recent``: what the patient did in their own latest
    sessions (``programs/recent.py``); with a program ``this_week``: its days done and
    asked this week, as the therapist's adherence counts them; ``patient_first_name``:
    the first word of the patient's name, which the kit page shows before a link
    replaces the kit it holds."""
    patient = db.get(models.Patient, device.patient_id)
    assert patient is not None  # a device goes with its patient (cascade)
    zone = request.app.state.services.settings.clinic_zone()
    day = clinic_today(zone)
    return {"device": device.name, "patient_first_name": (patient.name.split() or [""])[0],
            **todays_exercises(db, patient, day, zone),
            "discharged": patient.discharged_at is not None,
            "recent": recent_sessions(db, patient.id)}
