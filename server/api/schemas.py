"""Request and response bodies of the REST API (they make the OpenAPI document)."""

from __future__ import annotations

from datetime import date, datetime, timedelta, timezone
from typing import Annotated, Any, Literal

from armtrack.estimator.body import HEIGHT_RANGE_M
from fastapi import Path, Query
from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from pydantic_core import PydanticCustomError

from ..plain_text import Line

#: Row ids fit a 32-bit integer on every database the server runs on; a path or query id
#: beyond that is refused (422) before it reaches the database (SQLite raised
#: OverflowError on it: a 500).
MAX_ID = 2**31 - 1
Id = Annotated[int, Path(ge=1, le=MAX_ID)]
QueryId = Annotated[int | None, Query(ge=1, le=MAX_ID)]


#: The earliest date of birth taken: an earlier one is a typo (1026 for 1926).
EARLIEST_BIRTH = date(1900, 1, 1)


def _born(value: date) -> date:
    """A date of birth from EARLIEST_BIRTH to today (today anywhere: UTC+14), else a 422 in
    the form's words (a typed 2030 for 1930 was stored and printed on reports)."""
    today = datetime.now(timezone(timedelta(hours=14))).date()
    if value > today or value < EARLIEST_BIRTH:
        raise PydanticCustomError(
            "date_of_birth", "the date of birth {when} is {where}: give the patient's date of "
            "birth (YYYY-MM-DD)", {"when": value.isoformat(), "where": "after today"
                                   if value > today else f"before {EARLIEST_BIRTH.isoformat()}"})
    return value


DateOfBirth = Annotated[date, AfterValidator(_born)]


class TokenOut(BaseModel):
    access_token: str
    token_type: Literal["bearer"] = "bearer"
    expires_in: int = Field(description="seconds until the token expires")


class PatientIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: Line = Field(min_length=1, max_length=200)
    side: Literal["right", "left"] = Field(description="the arm followed")
    height_m: float = Field(ge=HEIGHT_RANGE_M[0], le=HEIGHT_RANGE_M[1],
                            description="body height [m], for segment lengths")
    clinic_number: Line | None = Field(None, max_length=64,
                                      description="the clinic's own patient number")
    date_of_birth: DateOfBirth | None = Field(
        None, description="ISO date, YYYY-MM-DD, from 1900-01-01 to today")


class PatientUpdate(BaseModel):
    """The fields to change; those left out stay (``null`` clears an optional one)."""

    model_config = ConfigDict(extra="forbid")
    name: Line | None = Field(None, min_length=1, max_length=200)
    side: Literal["right", "left"] | None = None
    height_m: float | None = Field(None, ge=HEIGHT_RANGE_M[0], le=HEIGHT_RANGE_M[1])
    clinic_number: Line | None = Field(None, max_length=64)
    date_of_birth: DateOfBirth | None = None


class PatientOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    side: Literal["right", "left"]
    height_m: float
    created_at: datetime
    clinic_number: str | None = None
    date_of_birth: date | None = None
    last_session_at: datetime | None = Field(
        None, description="when the patient's latest session started (lists only)")
    discharged_at: datetime | None = Field(
        None, description="when the therapist discharged the patient, null while in care "
        "(docs/extensions/discharge.md)")


class DeviceIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: Line = Field(min_length=1, max_length=200)


class DeviceOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    patient_id: int
    name: str
    created_at: datetime
    revoked_at: datetime | None
    last_session_at: datetime | None = Field(
        None, description="when the kit's newest session started (null: none yet): which "
        "of a patient's kits is still in use")


class DeviceCreated(DeviceOut):
    token: str = Field(description="the device token; shown this once, stored hashed")
    kit_url: str = Field(description="the phone kit's link with the token in its fragment "
                         "(docs/extensions/kit-link.md): shown this once")
    kit_qr: str = Field(description="a QR code of kit_url, an SVG data: URI")
    kit_url_secure: bool = Field(description="false when phones will not get motion "
                                 "sensors at kit_url (not https): set ARMTRACK_PUBLIC_URL")


class StoppedByServer(BaseModel):
    """The server stopped the session's stream (docs/extensions/stream-stopped.md)."""
    at: datetime = Field(description="when the server closed the stream (UTC)")
    close_code: int = Field(description="the close code the kit got: 4429")
    reason: str = Field(description="the close's reason, as the kit got it")
    refused: int = Field(description="the kit's messages refused in the window")
    refused_limit: int = Field(description="most refused messages a window allows "
                               "(ARMTRACK_REFUSED_LIMIT)")
    window_s: float = Field(description="the window [s] (ARMTRACK_REFUSED_WINDOW_S)")
    last_refused: str = Field(description="the last refused message's error reason")
    message: str = Field(description="what happened and what to do, for the therapist")


class SessionOut(BaseModel):
    id: int
    patient_id: int
    device_id: int | None
    device_name: str | None = Field(
        None, description="the kit's name as the therapist gave it (its device); null "
        "without one (an upload by a therapist, a removed kit)")
    source: Literal["stream", "upload"]
    status: Literal["live", "closed", "interrupted"]
    started_at: datetime
    ended_at: datetime | None
    side: Literal["right", "left"]
    sensors: list[str]
    nine_axis: dict[str, bool]
    samples: int
    rate_hz: float | None
    metadata: dict[str, str]
    measured_angles: list[str] = Field(
        description="the angles this session's kit measures (docs/extensions/"
        "measured-angles.md); the others stay 0 by the kinematics contract")
    assumptions: dict[str, str] = Field(
        description="what the measured angles assume, by name (e.g. upper_arm_still)")
    processed: bool = Field(description="estimates are stored for this session")
    calibration: dict[str, Any] | None
    estimator: dict[str, Any] | None
    processing_error: str | None
    dated: Literal["recorded", "uploaded", "streamed"] = Field(
        "streamed", description="what started_at is: when the file was recorded (its "
        "start_time header, docs/extensions/start-time.md), when it was uploaded (no such "
        "header), or when the kit's stream started")
    stopped_by_server: StoppedByServer | None = Field(
        None, description="the server stopped the session's stream: why, when and what "
        "to do (docs/extensions/stream-stopped.md); null when it never did")
    closed_after_silence: dict[str, Any] | None = Field(
        None, description="the server closed this interrupted session after its kit sent "
        "nothing for a long time: when, the last data, the setting and what it means "
        "(docs/extensions/closed-after-silence.md); null when it did not")
    carries_on: int | None = Field(
        None, description="the session of the same kit this one carries on (it was full or "
        "closed while the kit streamed; its calibration poses were held there): "
        "docs/extensions/carried-on.md; null otherwise")
