"""A clinic admin's routes: therapists (list, create, disable, enable, one-time password
reset) and patients' assignment to a covering therapist. An admin manages accounts; they
read no patient's data through these routes (the patient list gives ids, names and
therapists only, and is audited)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request, status
from pydantic import BaseModel, ConfigDict, Field, field_validator
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..auth import DEMO_USER, hash_password, new_token
from ..db import models
from ..plain_text import Line, Secret
from ..services import Services
from .auth_routes import ADMIN_RESET_REFUSED, MIN_PASSWORD
from .deps import Admin, Db, Page, services
from .schemas import MAX_ID, Id, QueryId

router = APIRouter(prefix="/api/admin", tags=["admin"], responses={
    401: {"description": "not signed in"},
    403: {"description": "only a clinic admin may do this"}})


class TherapistOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    username: str
    full_name: str | None = None
    is_admin: bool
    disabled_at: datetime | None
    created_at: datetime
    patients: int = Field(0, description="their patients in care (not discharged)")
    discharged_patients: int = Field(0, description="their discharged patients (care ended, "
                                     "records kept; docs/extensions/discharge.md)")


class TherapistIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    username: Line = Field(min_length=1, max_length=128, pattern=r"^[^\s]+$")
    password: Secret = Field(min_length=MIN_PASSWORD, max_length=1000)
    is_admin: bool = False
    full_name: Line | None = Field(None, max_length=200, description="as reports print it")

    @field_validator("username")
    @classmethod
    def not_the_demo_account(cls, name: str) -> str:
        if name.lower() == DEMO_USER:  # `armtrack serve` refuses a database holding it
            raise ValueError(f"the name {DEMO_USER!r} is kept for `armtrack demo`'s account: "
                             "choose another")
        return name


class ResetOut(BaseModel):
    reset_token: str = Field(description="one-time; give it to the therapist, it is shown once")
    expires_in: int = Field(description="seconds the token stays good [s]")


class Reassign(BaseModel):
    model_config = ConfigDict(extra="forbid")
    therapist_id: int = Field(ge=1, le=MAX_ID, description="the covering therapist")


class AdminPatientOut(BaseModel):
    id: int
    name: str
    therapist_id: int
    discharged_at: datetime | None = Field(
        None, description="when the therapist discharged the patient, null while in care "
        "(docs/extensions/discharge.md)")


def _therapist(db: DbSession, therapist_id: int) -> models.Therapist:
    therapist = db.get(models.Therapist, therapist_id)
    if therapist is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no therapist {therapist_id}")
    return therapist


def _counts(db: DbSession, ids: list[int]) -> dict[tuple[int, bool], int]:
    """(therapist id, discharged?) → their number of patients, for ``ids``."""
    discharged = models.Patient.discharged_at.is_not(None)
    rows = db.execute(select(models.Patient.therapist_id, discharged, func.count())
                      .where(models.Patient.therapist_id.in_(ids))
                      .group_by(models.Patient.therapist_id, discharged))
    return {(tid, bool(gone)): n for tid, gone, n in rows}


def _out(db: DbSession, therapist: models.Therapist,
         counts: dict[tuple[int, bool], int] | None = None) -> TherapistOut:
    counts = _counts(db, [therapist.id]) if counts is None else counts
    return TherapistOut.model_validate(therapist).model_copy(update={
        "patients": counts.get((therapist.id, False), 0),
        "discharged_patients": counts.get((therapist.id, True), 0)})


@router.get("/therapists", response_model=list[TherapistOut])
def list_therapists(db: Db, admin: Admin, page: Annotated[Page, Depends()]
                    ) -> list[TherapistOut]:
    """Every therapist and admin of the clinic, with their numbers of patients in care and
    discharged."""
    rows = list(db.scalars(select(models.Therapist).order_by(models.Therapist.username)
                           .limit(page.limit).offset(page.offset)))
    counts = _counts(db, [t.id for t in rows])
    return [_out(db, t, counts) for t in rows]


def _logged(db: DbSession, action: str, route: str, admin: models.Therapist,
            request: Request) -> None:
    """An admin's change of an account, in the audit log (not committed): the admin, the
    account in the route, the address. Before, none was written: an account enabled again
    (its patients stay with it) was then used with no entry of who opened it, or when."""
    audit.record(db, action=action, route=route, therapist_id=admin.id,
                 client=request.client.host if request.client else None, commit=False)


@router.post("/therapists", response_model=TherapistOut, status_code=status.HTTP_201_CREATED)
def create_therapist(body: TherapistIn, db: Db, admin: Admin, request: Request
                     ) -> TherapistOut:
    """A new therapist (or admin) account."""
    if db.scalar(select(models.Therapist).where(models.Therapist.username == body.username)):
        raise HTTPException(status.HTTP_409_CONFLICT, f"user {body.username!r} exists already")
    therapist = models.Therapist(username=body.username, is_admin=body.is_admin,
                                 password_hash=hash_password(body.password),
                                 full_name=(body.full_name or "").strip() or None)
    db.add(therapist)
    db.flush()
    _logged(db, "created_account", f"POST {request.url.path} (account {therapist.id})",
            admin, request)
    db.commit()
    return _out(db, therapist)


@router.post("/therapists/{therapist_id}/disable", response_model=TherapistOut)
async def disable_therapist(therapist_id: Id, admin: Admin, request: Request,
                            svc: Annotated[Services, Depends(services)]) -> TherapistOut:
    """Disable an account: it cannot sign in, its tokens and unused reset codes stop
    working and its live feeds and 3D views close at once. Its patients stay; reassign
    them to a covering therapist."""
    if therapist_id == admin.id:
        raise HTTPException(status.HTTP_409_CONFLICT, "an admin cannot disable themselves")

    def work(db: DbSession) -> TherapistOut:
        therapist = _therapist(db, therapist_id)
        if therapist.disabled_at is None:
            therapist.disabled_at = datetime.now(UTC)
        db.execute(delete(models.AccessToken)
                   .where(models.AccessToken.therapist_id == therapist_id))
        # a reset code made before dies with the account: whoever holds it must not set
        # the password that opens the account once it is enabled again
        db.execute(delete(models.PasswordReset).where(
            models.PasswordReset.therapist_id == therapist_id,
            models.PasswordReset.used_at.is_(None)))
        _logged(db, "disabled_account", f"POST {request.url.path}", admin, request)
        db.commit()
        return _out(db, therapist)

    out = await svc.run_db(work)
    await svc.access.recheck()
    return out


@router.post("/therapists/{therapist_id}/enable", response_model=TherapistOut)
def enable_therapist(therapist_id: Id, db: Db, admin: Admin, request: Request
                     ) -> TherapistOut:
    """Enable a disabled account again (it signs in afresh)."""
    therapist = _therapist(db, therapist_id)
    therapist.disabled_at = None
    _logged(db, "enabled_account", f"POST {request.url.path}", admin, request)
    db.commit()
    return _out(db, therapist)


@router.post("/therapists/{therapist_id}/reset", response_model=ResetOut)
def issue_reset(therapist_id: Id, db: Db, admin: Admin,
                svc: Annotated[Services, Depends(services)], request: Request) -> ResetOut:
    """A one-time reset token for a therapist who forgot their password (used with
    ``POST /api/auth/reset``; earlier unused ones stop working). One made for a disabled
    account sets nothing until the account is enabled; disabling it ends the token. Not
    for a clinic admin, the caller included (403): the code's holder would act in that
    admin's name, which the audit log could not tell apart (docs/security.md)."""
    if _therapist(db, therapist_id).is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, ADMIN_RESET_REFUSED.format(therapist_id))
    db.execute(delete(models.PasswordReset).where(
        models.PasswordReset.therapist_id == therapist_id,
        models.PasswordReset.used_at.is_(None)))
    token, digest = new_token("rt_")
    lifetime = timedelta(hours=svc.settings.reset_token_hours)
    db.add(models.PasswordReset(therapist_id=therapist_id, token_hash=digest,
                                issued_by=admin.id, expires_at=datetime.now(UTC) + lifetime))
    # logged: whoever holds the code chooses the account's password (the admin too)
    audit.record(db, action="issued_reset", route=f"POST {request.url.path}",
                 therapist_id=admin.id, client=request.client.host if request.client else None,
                 commit=False)
    db.commit()
    return ResetOut(reset_token=token, expires_in=int(lifetime.total_seconds()))


@router.get("/patients", response_model=list[AdminPatientOut])
def list_all_patients(db: Db, admin: Admin, page: Annotated[Page, Depends()],
                      therapist_id: QueryId = None,
                      discharged: bool | None = None) -> list[AdminPatientOut]:
    """Every patient's id, name, therapist (to reassign them) and discharge date; no
    clinical data. ``discharged=false`` keeps the patients in care, ``true`` the
    discharged ones, as ``GET /api/patients`` (docs/extensions/discharge.md)."""
    query = select(models.Patient)
    if therapist_id is not None:
        query = query.where(models.Patient.therapist_id == therapist_id)
    if discharged is not None:
        query = query.where(models.Patient.discharged_is(discharged))
    rows = db.scalars(query.order_by(models.Patient.id).limit(page.limit).offset(page.offset))
    return [_admin_patient(p) for p in rows]


def _admin_patient(p: models.Patient) -> AdminPatientOut:
    return AdminPatientOut(id=p.id, name=p.name, therapist_id=p.therapist_id,
                           discharged_at=p.discharged_at)


@router.post("/patients/{patient_id}/reassign", response_model=AdminPatientOut)
async def reassign_patient(patient_id: Id, body: Reassign, admin: Admin,
                           svc: Annotated[Services, Depends(services)]) -> AdminPatientOut:
    """Give a patient (with their sessions and kits) to a covering therapist; the former
    therapist's live feeds and 3D views of them close at once."""
    def work(db: DbSession) -> AdminPatientOut:
        patient = db.get(models.Patient, patient_id)
        if patient is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no patient {patient_id}")
        target = _therapist(db, body.therapist_id)
        if target.disabled_at is not None:
            raise HTTPException(status.HTTP_409_CONFLICT,
                                f"therapist {target.id} is disabled: choose an active one")
        if target.is_admin:  # an admin holds no patients, themself included
            raise HTTPException(status.HTTP_409_CONFLICT,
                                f"therapist {target.id} is a clinic admin, who holds no "
                                "patients: choose a therapist")
        patient.therapist_id = target.id
        db.commit()
        audit.note(patient_id=patient.id)
        return _admin_patient(patient)

    out = await svc.run_db(work)
    await svc.access.recheck()
    return out
