"""What a kit is given today when a program is in force (``server/programs/stream.py``'s
``device_today``, for the phone kit's device-scoped read): the most recent program in
force, its current version and exercises in order with dose and target band; nothing
before its start, after its end or once it is ended. On a real database file."""

from __future__ import annotations

from datetime import date

import pytest
from armtrack.server.db.engine import make_engine, make_sessionmaker
from armtrack.server.db.migrate import upgrade
from armtrack.server.programs import store, stream
from armtrack.server.programs.schemas import PrescriptionIn, ProgramIn
from server_support import add_patient

ELBOW = {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5,
         "target_min_deg": 5, "target_max_deg": 110}


@pytest.fixture
def db(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'today.db'}")
    upgrade(engine)
    with make_sessionmaker(engine)() as session:
        yield session
    engine.dispose()


def test_the_program_in_force_today_is_what_the_kit_guides(db):
    patient = add_patient(db, "Today")
    db.commit()
    assert stream.device_today(db, patient, date(2026, 12, 1)) is None  # no program
    program = store.create_program(db, patient.id, ProgramIn(
        name="Morning", start_date=date(2026, 12, 1), end_date=date(2026, 12, 31),
        exercises=[ELBOW, {"exercise": "pronation", "sets": 1, "repetitions": 6,
                           "days_per_week": 3}]), therapist_id=1)
    assert stream.device_today(db, patient, date(2026, 11, 30)) is None  # not yet
    today = stream.device_today(db, patient, date(2026, 12, 2))
    assert today["source"] == "program"
    changed_at = today["program"].pop("changed_at")  # when version 1 was saved
    assert changed_at == program.versions[-1].created_at.replace(tzinfo=changed_at.tzinfo)
    assert today["program"] == {"id": program.id, "name": "Morning", "version": 1,
                                "note": None}
    assert [e["name"] for e in today["exercises"]] == ["elbow_flexion", "pronation"]
    elbow = today["exercises"][0]
    assert (elbow["sets"], elbow["repetitions"], elbow["angle"], elbow["sensor"]) == (
        2, 10, "elbow_flexion", "forearm")
    assert elbow["target"] == {"min_deg": 5, "max_deg": 110, "from": "program"}
    assert [e["days_per_week"] for e in today["exercises"]] == [5, 3]  # how often
    store.change_program(db, program, PrescriptionIn(
        start_date=date(2026, 12, 1), exercises=[{**ELBOW, "sets": 3}]), therapist_id=1)
    today = stream.device_today(db, patient, date(2026, 12, 2))
    assert today["program"]["version"] == 2 and today["exercises"][0]["sets"] == 3
    assert stream.device_today(db, patient, date(2027, 2, 1))["program"]["version"] == 2
    store.end_program(db, program)
    assert stream.device_today(db, patient, date(2026, 12, 2)) is None
