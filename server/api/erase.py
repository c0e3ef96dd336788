"""Erasing a session or a patient with everything stored of them."""

from __future__ import annotations

from sqlalchemy import delete, select
from sqlalchemy.orm import Session as DbSession

from ..db import models


def erase_session(db: DbSession, session_id: int) -> None:
    """Delete a session's blocks, marks, estimates and streams, then the session."""
    for table in (models.SampleBlock, models.EstimateBlock, models.Mark, models.Stream):
        db.execute(delete(table).where(table.session_id == session_id))
    db.execute(delete(models.Session).where(models.Session.id == session_id))
    db.commit()


def erase_patient(db: DbSession, patient_id: int) -> None:
    """Delete all of a patient's sessions and devices, then the patient."""
    for session_id in db.scalars(select(models.Session.id)
                                 .where(models.Session.patient_id == patient_id)).all():
        erase_session(db, session_id)
    db.execute(delete(models.Device).where(models.Device.patient_id == patient_id))
    db.execute(delete(models.Patient).where(models.Patient.id == patient_id))
    db.commit()
