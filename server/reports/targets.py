"""Targets: the range a therapist prescribes for one joint angle of one patient [deg],
in ``spec/kinematics.md``'s names and signs (elbow 0…120: flex to 120° and extend fully).
Reports and progress show each session against them: ``percent_of_target`` = range ÷
(target_max − target_min) × 100, and ``target_reached`` when the session's minimum is at
or below the target's and its maximum at or above (both ends reached)."""

from __future__ import annotations

from datetime import UTC, datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..db import models

#: Angles can be set within this [deg].
LIMIT_DEG = 180.0


class TargetIn(BaseModel):
    """A target range [deg]; ``min_deg`` < ``max_deg``."""

    model_config = ConfigDict(extra="forbid")
    min_deg: float = Field(ge=-LIMIT_DEG, le=LIMIT_DEG, allow_inf_nan=False)
    max_deg: float = Field(ge=-LIMIT_DEG, le=LIMIT_DEG, allow_inf_nan=False)
    note: str | None = Field(None, max_length=500)

    @model_validator(mode="after")
    def _ordered(self) -> TargetIn:
        if not self.min_deg < self.max_deg:
            raise ValueError(f"min_deg must be below max_deg, got {self.min_deg} and "
                             f"{self.max_deg}")
        return self


def patient_targets(db: DbSession, patient_id: int) -> dict[str, models.PatientTarget]:
    """The patient's targets, angle → row, in angle-name order."""
    rows = db.scalars(select(models.PatientTarget)
                      .where(models.PatientTarget.patient_id == patient_id)
                      .order_by(models.PatientTarget.angle))
    return {row.angle: row for row in rows}


def set_target(db: DbSession, patient_id: int, angle: str,
               body: TargetIn) -> models.PatientTarget:
    """Create or replace the patient's target for ``angle`` (committed)."""
    row = db.scalar(select(models.PatientTarget).where(
        models.PatientTarget.patient_id == patient_id, models.PatientTarget.angle == angle))
    if row is None:
        row = models.PatientTarget(patient_id=patient_id, angle=angle)
        db.add(row)
    row.min_deg, row.max_deg, row.note = body.min_deg, body.max_deg, body.note
    row.updated_at = datetime.now(UTC)
    db.commit()
    return row


def delete_target(db: DbSession, patient_id: int, angle: str) -> bool:
    """Remove the patient's target for ``angle`` (committed); False when there was none."""
    row = db.scalar(select(models.PatientTarget).where(
        models.PatientTarget.patient_id == patient_id, models.PatientTarget.angle == angle))
    if row is None:
        return False
    db.delete(row)
    db.commit()
    return True
