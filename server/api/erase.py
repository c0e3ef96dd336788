"""Erasing a session or a patient with everything stored of them, for good: the rows are
deleted (SQLite runs with ``secure_delete``, so freed pages are overwritten with zeros)
and the write-ahead log is checkpointed and truncated, so no copy of the erased data stays
readable in the database's files. The retention task erases closed sessions older than
``ARMTRACK_RETENTION_DAYS``; each erasure is in the audit log."""

from __future__ import annotations

import logging
from datetime import UTC, datetime, timedelta

from sqlalchemy import and_, delete, or_, select
from sqlalchemy.orm import Session as DbSession

from .. import audit
from ..db import models

log = logging.getLogger("armtrack.erase")

#: How far past its arrival an uploaded session's end may count for retention.
UPLOAD_END_SLACK = timedelta(days=1)


def _delete_session_rows(db: DbSession, session_id: int) -> None:
    for table in (models.SampleBlock, models.EstimateBlock, models.Mark, models.Stream,
                  models.SessionRating, models.SessionProgram):
        db.execute(delete(table).where(table.session_id == session_id))
    db.execute(delete(models.Session).where(models.Session.id == session_id))


def scrub_files(db: DbSession) -> None:
    """Checkpoint SQLite's write-ahead log into the database and truncate it: the log
    holds copies of pages written before the erasure (no-op on other databases)."""
    if db.get_bind().dialect.name == "sqlite":
        db.connection().exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
        db.commit()


def erase_session(db: DbSession, session_id: int) -> None:
    """Delete a session's blocks, marks, estimates and streams, then the session."""
    _delete_session_rows(db, session_id)
    db.commit()
    scrub_files(db)


def erase_patient(db: DbSession, patient_id: int) -> None:
    """Delete all of a patient's sessions, targets, programs and devices, then the
    patient."""
    for session_id in db.scalars(select(models.Session.id)
                                 .where(models.Session.patient_id == patient_id)).all():
        _delete_session_rows(db, session_id)
    db.execute(delete(models.PatientTarget).where(models.PatientTarget.patient_id == patient_id))
    programs = select(models.Program.id).where(models.Program.patient_id == patient_id)
    versions = select(models.ProgramVersion.id).where(
        models.ProgramVersion.program_id.in_(programs))
    db.execute(delete(models.ProgramExercise).where(
        models.ProgramExercise.version_id.in_(versions)))
    db.execute(delete(models.ProgramVersion).where(models.ProgramVersion.id.in_(versions)))
    db.execute(delete(models.Program).where(models.Program.patient_id == patient_id))
    db.execute(delete(models.PatientTargetVersion)
               .where(models.PatientTargetVersion.patient_id == patient_id))
    db.execute(delete(models.KitGyroBias).where(models.KitGyroBias.device_id.in_(
        select(models.Device.id).where(models.Device.patient_id == patient_id))))
    db.execute(delete(models.Device).where(models.Device.patient_id == patient_id))
    db.execute(delete(models.Patient).where(models.Patient.id == patient_id))
    db.commit()
    scrub_files(db)


def erase_expired(db: DbSession, retention_days: float, now: datetime | None = None
                  ) -> list[int]:
    """Erase the closed sessions that ended more than ``retention_days`` ago, each logged
    as ``erased_retention``; returns their ids. An uploaded session was recorded before
    it arrived, whatever its times say (``started_at`` + its span of ``t``, which may step
    a day at a time: 3650 rows made one 'end' in ten years): it is past the period at the
    latest ``UPLOAD_END_SLACK`` after its arrival is (the slack ``start_time`` has too)."""
    cutoff = (now or datetime.now(UTC)) - timedelta(days=retention_days)
    expired = db.execute(select(models.Session.id, models.Session.patient_id).where(
        models.Session.status == "closed", models.Session.ended_at.is_not(None),
        or_(models.Session.ended_at < cutoff,
            and_(models.Session.source == "upload",
                 models.Session.created_at < cutoff - UPLOAD_END_SLACK)))).all()
    for session_id, patient_id in expired:
        _delete_session_rows(db, session_id)
        audit.record(db, action="erased_retention", route="retention", patient_id=patient_id,
                     session_id=session_id, commit=False)
        db.commit()
    if expired:
        scrub_files(db)
        log.info("retention: erased %d closed session(s) older than %g days",
                 len(expired), retention_days)
    return [s for s, _ in expired]
