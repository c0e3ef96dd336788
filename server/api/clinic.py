"""The clinic and the signed-in therapist: what pages and reports print in their headers
(the clinic's name, address and time zone from ``ARMTRACK_CLINIC_*``; the therapist's
full name on the account)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends
from pydantic import BaseModel, ConfigDict, Field

from ..plain_text import Line
from ..services import Services
from .deps import Db, Therapist, services

router = APIRouter(prefix="/api", tags=["clinic"], responses={
    401: {"description": "not signed in"}})


class ClinicOut(BaseModel):
    name: str = Field(description="ARMTRACK_CLINIC_NAME; empty when unset")
    address: str = Field(description="ARMTRACK_CLINIC_ADDRESS; empty when unset")
    time_zone: str = Field(description="IANA time zone pages and reports show times in "
                           "(ARMTRACK_CLINIC_TIMEZONE, default UTC)")
    clock: Literal["24h", "12h"] = Field(description="the clinic's clock pages and reports "
                                         "write times in: 24h (22:39) or 12h (10:39 PM) "
                                         "(ARMTRACK_CLINIC_CLOCK, default 24h)")


class MeOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    username: str
    full_name: str | None
    is_admin: bool


class MeIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    full_name: Line | None = Field(max_length=200, description="as reports print it; null "
                                  "or empty: the user name")


@router.get("/clinic", response_model=ClinicOut)
def get_clinic(therapist: Therapist, svc: Annotated[Services, Depends(services)]
               ) -> ClinicOut:
    """The clinic's name, address and time zone."""
    s = svc.settings
    return ClinicOut(name=s.clinic_name, address=s.clinic_address, time_zone=s.clinic_timezone,
                     clock=s.clinic_clock)


@router.get("/me", response_model=MeOut)
def get_me(therapist: Therapist) -> MeOut:
    """The signed-in account."""
    return MeOut.model_validate(therapist)


@router.patch("/me", response_model=MeOut)
def update_me(body: MeIn, db: Db, therapist: Therapist) -> MeOut:
    """Set your full name (as reports print it)."""
    therapist.full_name = (body.full_name or "").strip() or None
    db.commit()
    return MeOut.model_validate(therapist)
