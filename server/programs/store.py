"""Programs in the database: create, change (a new version), end, read
(``docs/programs.md``). Versions are never changed once saved."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import date, datetime

from sqlalchemy import func, select
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models
from . import catalogue
from .calendar import aware
from .schemas import ExerciseOut, PrescriptionIn, ProgramIn, ProgramOut, VersionOut


class ProgramConflict(Exception):
    """A program of that name exists already for the patient."""


def name_taken(db: DbSession, patient_id: int, name: str) -> bool:
    return db.scalar(select(func.count()).select_from(models.Program).where(
        models.Program.patient_id == patient_id, models.Program.name == name)) > 0


def _add_version(db: DbSession, program: models.Program, number: int,
                 body: PrescriptionIn, therapist_id: int, now: datetime
                 ) -> models.ProgramVersion:
    version = models.ProgramVersion(
        program_id=program.id, number=number, created_at=now, created_by=therapist_id,
        start_date=body.start_date, end_date=body.end_date, note=body.note)
    for position, e in enumerate(body.exercises):
        version.exercises.append(models.ProgramExercise(
            position=position, exercise=e.exercise, angle=catalogue.CATALOGUE[e.exercise].angle,
            sets=e.sets, repetitions=e.repetitions, target_min_deg=e.target_min_deg,
            target_max_deg=e.target_max_deg, hold_s=e.hold_s, rest_s=e.rest_s,
            days_per_week=e.days_per_week, note=e.note))
    db.add(version)
    return version


def create_program(db: DbSession, patient_id: int, body: ProgramIn,
                   therapist_id: int) -> models.Program:
    """A new program with its version 1 (committed); ProgramConflict when the name is
    taken."""
    if name_taken(db, patient_id, body.name):
        raise ProgramConflict(f"the patient has a program named {body.name!r} already")
    now = clock.now()
    program = models.Program(patient_id=patient_id, name=body.name, created_at=now)
    db.add(program)
    db.flush()
    _add_version(db, program, 1, body, therapist_id, now)
    db.commit()
    return program


def change_program(db: DbSession, program: models.Program, body: PrescriptionIn,
                   therapist_id: int) -> models.ProgramVersion:
    """Save ``body`` as the program's next version (committed)."""
    number = (program.versions[-1].number + 1) if program.versions else 1
    version = _add_version(db, program, number, body, therapist_id, clock.now())
    program.ended_at = None
    db.commit()
    db.refresh(program)
    return version


def end_program(db: DbSession, program: models.Program) -> None:
    if program.ended_at is None:
        program.ended_at = clock.now()
        db.commit()


def patient_programs(db: DbSession, patient_id: int) -> list[models.Program]:
    return list(db.scalars(select(models.Program)
                           .where(models.Program.patient_id == patient_id)
                           .order_by(models.Program.created_at, models.Program.id)))


def find_program(db: DbSession, patient_id: int, ref: int | str) -> models.Program | None:
    """The patient's program by id or by name."""
    query = select(models.Program).where(models.Program.patient_id == patient_id)
    if isinstance(ref, int):
        query = query.where(models.Program.id == ref)
    else:
        query = query.where(models.Program.name == ref)
    return db.scalar(query)


def version_in_force(program: models.Program, moment: datetime
                     ) -> models.ProgramVersion | None:
    """The version saved last at or before ``moment`` (None before the first)."""
    found = None
    for version in program.versions:
        if aware(version.created_at) <= aware(moment):
            found = version
    return found


def is_active(program: models.Program, day: date) -> bool:
    """Not ended, and ``day`` within the current version's dates."""
    if program.ended_at is not None or not program.versions:
        return False
    v = program.versions[-1]
    return v.start_date <= day and (v.end_date is None or day <= v.end_date)


def resolve_target(exercise: models.ProgramExercise,
                   patient_targets: Mapping[str, models.PatientTarget]
                   ) -> tuple[tuple[float, float], str]:
    """The target [deg] of an exercise and where it comes from: the version's, else the
    patient's target for its angle, else the catalogue's."""
    if exercise.target_min_deg is not None and exercise.target_max_deg is not None:
        return (exercise.target_min_deg, exercise.target_max_deg), "program"
    target = patient_targets.get(exercise.angle)
    if target is not None:
        return (target.min_deg, target.max_deg), "patient"
    entry = catalogue.CATALOGUE[exercise.exercise]
    return (entry.rest_deg, entry.target_deg), "catalogue"


def exercise_out(e: models.ProgramExercise,
                 patient_targets: Mapping[str, models.PatientTarget]) -> ExerciseOut:
    target, source = resolve_target(e, patient_targets)
    return ExerciseOut(
        exercise=e.exercise, title=catalogue.CATALOGUE[e.exercise].title, angle=e.angle,
        sets=e.sets, repetitions=e.repetitions, target_min_deg=e.target_min_deg,
        target_max_deg=e.target_max_deg, target=target, target_source=source,
        hold_s=e.hold_s, rest_s=e.rest_s, days_per_week=e.days_per_week, note=e.note)


def version_out(v: models.ProgramVersion,
                patient_targets: Mapping[str, models.PatientTarget]) -> VersionOut:
    return VersionOut(id=v.id, number=v.number, created_at=aware(v.created_at),
                      created_by=v.created_by, start_date=v.start_date, end_date=v.end_date,
                      note=v.note,
                      exercises=[exercise_out(e, patient_targets) for e in v.exercises])


def program_out(program: models.Program, patient_targets: Mapping[str, models.PatientTarget],
                today: date) -> ProgramOut:
    return ProgramOut(
        id=program.id, patient_id=program.patient_id, name=program.name,
        created_at=aware(program.created_at),
        ended_at=aware(program.ended_at) if program.ended_at else None,
        active=is_active(program, today),
        version=version_out(program.versions[-1], patient_targets))


def patient_kits(db: DbSession, patient_id: int) -> list[tuple[str, tuple[str, ...]]]:
    """The patient's kits as their sessions show them: (device name, the sensors a
    session streamed with) for each sensor set of each unrevoked device, oldest first.
    A phone worn on either segment gives one set per segment."""
    rows = db.execute(
        select(models.Device.name, models.Session.sensors)
        .join(models.Session, models.Session.device_id == models.Device.id)
        .where(models.Device.patient_id == patient_id, models.Device.revoked_at.is_(None))
        .order_by(models.Session.id))
    seen: dict[tuple[str, tuple[str, ...]], None] = {}
    for name, sensors in rows:
        seen[(name, tuple(sorted(sensors or {})))] = None
    return list(seen)
