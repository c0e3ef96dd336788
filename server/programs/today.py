"""What a patient's device guides today (``docs/extensions/device-today.md``): the
exercises, each with its target band, for the phone on either segment.

With a program in force today (the clinic's day, ``docs/programs.md``) these are the
program's exercises with their dose and the program's id, name and version
(``stream.device_today``); without one, the catalogue's default session per segment, each
exercise's band the patient's target for its angle where the therapist set one.
``todays_exercises`` is the one place the kit's list comes from.
"""

from __future__ import annotations

from datetime import date
from typing import Any
from zoneinfo import ZoneInfo

from sqlalchemy.orm import Session as DbSession

from ..db import models
from ..reports.targets import patient_targets
from .adherence import this_week
from .catalogue import CATALOGUE, DEFAULT_SESSION, phone_fields
from .stream import device_today

#: Version of the device-today answer (``docs/extensions/device-today.md``).
DEVICE_TODAY_VERSION = 1


def todays_exercises(db: DbSession, patient: models.Patient, today: date,
                     zone: ZoneInfo) -> dict[str, Any]:
    """The answer of ``GET /api/device/today`` for ``patient`` on the clinic's day
    ``today`` (in the clinic's ``zone``): ``source`` (``program`` or ``default``) and
    ``exercises``, in order, each the catalogue's fields plus ``target``: ``{"min_deg",
    "max_deg", "from"}``; with a program also ``program``, each exercise's dose
    (``programs-hello.md``) and ``this_week``: the week's days done and asked, by the
    therapist's adherence rule (``adherence.this_week``)."""
    program = device_today(db, patient, today)
    if program is not None:
        # the program device_today read (in the session already: no query)
        followed = db.get(models.Program, program["program"]["id"])
        assert followed is not None
        return {"version": DEVICE_TODAY_VERSION, **program,
                "this_week": this_week(db, patient.id, followed, today, zone)}
    targets = patient_targets(db, patient.id)
    exercises = []
    for sensor, names in DEFAULT_SESSION.items():
        for name in names:
            entry = CATALOGUE[name]
            target = targets.get(entry.angle)
            band = ({"min_deg": target.min_deg, "max_deg": target.max_deg, "from": "patient"}
                    if target is not None else
                    {"min_deg": entry.rest_deg, "max_deg": entry.target_deg, "from": "default"})
            exercises.append({**entry.as_dict(), "sensor": sensor, "target": band,
                              **phone_fields(entry)})
    return {"version": DEVICE_TODAY_VERSION, "source": "default", "side": patient.side,
            "exercises": exercises}


def exercise_bands(db: DbSession, patient_id: int) -> dict[str, tuple[str, float, float]]:
    """Every catalogue exercise's (angle, min_deg, max_deg) for the patient: the
    therapist's target for its angle where set, else the catalogue's default band."""
    targets = patient_targets(db, patient_id)
    bands = {}
    for name, entry in CATALOGUE.items():
        target = targets.get(entry.angle)
        bands[name] = ((entry.angle, target.min_deg, target.max_deg) if target is not None
                       else (entry.angle, entry.rest_deg, entry.target_deg))
    return bands
