"""Targets: the range a therapist prescribes for one joint angle of one patient [deg],
in ``docs/spec/kinematics.md``'s names and signs (elbow 0…120: flex to 120° and extend fully).
Reports and progress show each session against them with the side rule of
``percent_of_normal`` (``docs/spec/api.md``): ``percent_of_target`` =
max(max ÷ target_max, min ÷ target_min) × 100, a term only for a side the target has
(``target_max > 0``, ``target_min < 0``), clamped at 0; ``target_reached`` when that is
at least 100 % (so the percentage and the tick agree).

**A report is a record.** Every setting and removal is kept as a version
(``PatientTargetVersion``); a session is judged against the targets *in force when it
started* (``targets_at``), and today's targets (``patient_targets``) are shown beside
them. One source of targets: the programs feature reads them from here too."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..plain_text import Note
from ..programs.calendar import aware

#: Angles can be set within this [deg].
LIMIT_DEG = 180.0


class TargetIn(BaseModel):
    """A target range [deg]; ``min_deg`` < ``max_deg``."""

    model_config = ConfigDict(extra="forbid")
    min_deg: float = Field(ge=-LIMIT_DEG, le=LIMIT_DEG, allow_inf_nan=False)
    max_deg: float = Field(ge=-LIMIT_DEG, le=LIMIT_DEG, allow_inf_nan=False)
    note: Note | None = Field(None, max_length=500)

    @model_validator(mode="after")
    def _ordered(self) -> TargetIn:
        if not self.min_deg < self.max_deg:
            raise ValueError(f"min_deg must be below max_deg, got {self.min_deg} and "
                             f"{self.max_deg}")
        return self


@dataclass(frozen=True)
class Target:
    """A target as it was in force [deg]; ``set_at`` when it was set (UTC)."""

    angle: str
    min_deg: float
    max_deg: float
    note: str | None
    set_at: datetime


def _target(row: models.PatientTarget | models.PatientTargetVersion) -> Target:
    at = row.set_at if isinstance(row, models.PatientTargetVersion) else row.updated_at
    return Target(angle=row.angle, min_deg=row.min_deg, max_deg=row.max_deg, note=row.note,
                  set_at=at)


def current_targets(db: DbSession, patient_id: int) -> dict[str, Target]:
    """Today's targets, angle → target, in angle-name order."""
    return {k: _target(v) for k, v in patient_targets(db, patient_id).items()}


def targets_at(db: DbSession, patient_id: int, moment: datetime) -> dict[str, Target]:
    """The targets in force at ``moment``: per angle, its last version set at or before
    it, unless that version removed it. Angle → target, in angle-name order."""
    rows = db.scalars(select(models.PatientTargetVersion)
                      .where(models.PatientTargetVersion.patient_id == patient_id,
                             models.PatientTargetVersion.set_at <= moment)
                      .order_by(models.PatientTargetVersion.set_at,
                                models.PatientTargetVersion.id))
    return targets_in(rows, moment)


def targets_in(history: Iterable[models.PatientTargetVersion], moment: datetime
               ) -> dict[str, Target]:
    """``targets_at`` from the patient's versions (``target_history``, oldest first; those
    set after ``moment`` are passed over), for many moments from one read."""
    last: dict[str, models.PatientTargetVersion] = {}
    for row in history:
        if aware(row.set_at) <= moment:
            last[row.angle] = row
    return {angle: _target(last[angle]) for angle in sorted(last)
            if last[angle].min_deg is not None and last[angle].max_deg is not None}


def target_history(db: DbSession, patient_id: int) -> list[models.PatientTargetVersion]:
    """Every version of the patient's targets, oldest first."""
    return list(db.scalars(select(models.PatientTargetVersion)
                           .where(models.PatientTargetVersion.patient_id == patient_id)
                           .order_by(models.PatientTargetVersion.set_at,
                                     models.PatientTargetVersion.id)))


def patient_targets(db: DbSession, patient_id: int) -> dict[str, models.PatientTarget]:
    """The patient's targets, angle → row, in angle-name order."""
    rows = db.scalars(select(models.PatientTarget)
                      .where(models.PatientTarget.patient_id == patient_id)
                      .order_by(models.PatientTarget.angle))
    return {row.angle: row for row in rows}


def set_target(db: DbSession, patient_id: int, angle: str, body: TargetIn,
               set_by: int | None = None) -> models.PatientTarget:
    """Create or replace the patient's target for ``angle``, keeping the version
    (committed)."""
    row = db.scalar(select(models.PatientTarget).where(
        models.PatientTarget.patient_id == patient_id, models.PatientTarget.angle == angle))
    if row is None:
        row = models.PatientTarget(patient_id=patient_id, angle=angle)
        db.add(row)
    now = datetime.now(UTC)
    row.min_deg, row.max_deg, row.note = body.min_deg, body.max_deg, body.note
    row.updated_at = now
    db.add(models.PatientTargetVersion(patient_id=patient_id, angle=angle,
                                       min_deg=body.min_deg, max_deg=body.max_deg,
                                       note=body.note, set_at=now, set_by=set_by))
    db.commit()
    return row


def delete_target(db: DbSession, patient_id: int, angle: str,
                  set_by: int | None = None) -> bool:
    """Remove the patient's target for ``angle``, keeping the removal as a version
    (committed); False when there was none."""
    row = db.scalar(select(models.PatientTarget).where(
        models.PatientTarget.patient_id == patient_id, models.PatientTarget.angle == angle))
    if row is None:
        return False
    db.delete(row)
    db.add(models.PatientTargetVersion(patient_id=patient_id, angle=angle, min_deg=None,
                                       max_deg=None, note=None, set_at=datetime.now(UTC),
                                       set_by=set_by))
    db.commit()
    return True
