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


def test_this_weeks_days_are_the_adherence_weeks_read_in_a_few_queries(db, monkeypatch):
    # the phone's "This week: 2 of 3 days done" (device-today's this_week) is the
    # therapist's week (adherence.weeks: prescribed.days, done.days) by one rule
    # (adherence.week_days), read without building any report, in a few queries however
    # many sessions the patient had before the week
    from datetime import UTC, datetime, timedelta
    from zoneinfo import ZoneInfo

    from armtrack.server.db import models
    from armtrack.server.programs import adherence
    from armtrack.server.settings import Settings
    from sqlalchemy import event

    zone = ZoneInfo("Europe/Zurich")
    patient = add_patient(db, "Weekly")
    program = store.create_program(db, patient.id, ProgramIn(
        name="Weekly", start_date=date(2026, 9, 7),
        exercises=[{**ELBOW, "days_per_week": 3}]), therapist_id=1)
    version = program.versions[-1]

    def session(at: datetime) -> None:
        s = models.Session(patient_id=patient.id, source="stream", status="closed",
                           side="right", sensors={}, started_at=at)
        db.add(s)
        db.flush()
        db.add(models.SessionProgram(session_id=s.id, version_id=version.id))

    for day in range(80):  # the weeks before: many sessions, none of this week
        session(datetime(2026, 9, 7, 9, tzinfo=UTC) + timedelta(days=day))
    session(datetime(2026, 11, 29, 22, 30, tzinfo=UTC))  # Sun 23:30 in Zurich: last week
    session(datetime(2026, 11, 29, 23, 30, tzinfo=UTC))  # Mon 00:30 in Zurich: this week
    session(datetime(2026, 11, 30, 17, 0, tzinfo=UTC))   # the same Monday again
    session(datetime(2026, 12, 2, 8, 0, tzinfo=UTC))     # Wednesday
    db.commit()

    def no_report(*args, **kwargs):
        raise AssertionError("this_week built a report")

    monkeypatch.setattr(adherence.content, "session_report", no_report)
    statements = []
    listen = lambda *a: statements.append(a[2])  # noqa: E731
    event.listen(db.get_bind(), "before_cursor_execute", listen)
    try:
        week = adherence.this_week(db, patient.id, program, date(2026, 12, 2), zone)
    finally:
        event.remove(db.get_bind(), "before_cursor_execute", listen)
    print(f"\nthis_week: {week}; {len(statements)} statements")
    assert week == {"week": "2026-W49", "monday": date(2026, 11, 30), "days_done": 2,
                    "days_asked": 3, "today_done": True, "shortened": None,
                    "changed_on": None}
    assert len(statements) <= 6, statements
    monkeypatch.undo()
    therapist = {w.week: w for w in adherence.patient_programs_progress(
        db, patient, Settings(clinic_timezone="Europe/Zurich"),
        now=datetime(2026, 12, 2, 12, tzinfo=UTC))[0].weeks}
    assert (therapist["2026-W49"].done.days, therapist["2026-W49"].prescribed.days) == (2, 3)
    last = adherence.this_week(db, patient.id, program, date(2026, 11, 29), zone)
    assert (last["week"], last["days_done"], last["today_done"]) == ("2026-W48", 4, True)
    assert (therapist["2026-W48"].done.days, therapist["2026-W48"].prescribed.days) == (4, 3)


def test_progress_rows_take_their_targets_in_a_few_queries_and_the_band_of_the_raise_done(db):
    # "Target then" of the progress list: 100 sessions read their targets in a few queries
    # for all (it was ~3 a row), and an angle two exercises of the version give different
    # bands (a forward and a side raise: shoulder_elevation) takes the band of the one
    # the session did; a session that did both keeps none (its range is over both)
    from datetime import UTC, datetime, timedelta

    from armtrack.server.db import models
    from armtrack.server.reports import progress
    from armtrack.server.reports.content import RomEntry, report_key
    from sqlalchemy import event

    patient = add_patient(db, "Raises")
    program = store.create_program(db, patient.id, ProgramIn(
        name="Raises", start_date=date(2026, 9, 7), exercises=[
            {"exercise": "shoulder_flexion", "sets": 1, "repetitions": 5, "days_per_week": 3,
             "target_min_deg": 0, "target_max_deg": 140},
            {"exercise": "shoulder_abduction", "sets": 1, "repetitions": 5,
             "days_per_week": 3, "target_min_deg": 0, "target_max_deg": 100}]),
        therapist_id=1)
    version = program.versions[-1]
    sessions = []
    for day in range(100):
        s = models.Session(patient_id=patient.id, source="stream", status="closed",
                           side="right", sensors={}, samples=10,
                           started_at=datetime(2026, 9, 7, 9, tzinfo=UTC) + timedelta(days=day))
        db.add(s)
        db.flush()
        db.add(models.SessionProgram(session_id=s.id, version_id=version.id))
        sessions.append(s)
    db.commit()
    rom = RomEntry(min=5.0, max=120.0, range=115.0, normal_min=0.0, normal_max=180.0,
                   percent_of_normal=66.7, paper_min=None, paper_max=None,
                   percent_of_paper=None, samples=100)
    did = {0: ("shoulder_flexion",), 1: ("shoulder_abduction",)}
    for i, s in enumerate(sessions):  # the rows as kept once read (no report built here)
        row = progress.SessionProgress(
            session_id=s.id, started_at=s.started_at, status="closed", processed=True,
            processing_error=None, rom={"shoulder_elevation": rom}, repetitions={},
            median_sparc={}, peak_velocity_deg_s={})
        progress._ROWS.put(report_key(s), (row.model_dump_json().encode(),
                                           did.get(i, ("shoulder_flexion", "shoulder_abduction"))))
    statements = []
    listen = lambda *a: statements.append(a[2])  # noqa: E731
    event.listen(db.get_bind(), "before_cursor_execute", listen)
    try:
        rows = progress.session_rows(db, patient.id, sessions)
    finally:
        event.remove(db.get_bind(), "before_cursor_execute", listen)
    print(f"\n100 progress rows: {len(statements)} statements")
    assert len(statements) <= 4, statements
    bands = [(r.rom["shoulder_elevation"].target_min, r.rom["shoulder_elevation"].target_max)
             for r in rows]
    assert bands[0] == (0, 140) and bands[1] == (0, 100)  # the raise done: its band
    assert set(bands[2:]) == {(None, None)}  # both raises: no one band
    # the session's report (page, PDF, CSV, FHIR) by the same rule: its cached report,
    # made without targets, judged now (content.session_report)
    from armtrack.server.reports import content

    for i, s in enumerate(sessions[:3]):
        exercises = [content.Exercise(name=n, source="marks", start_s=0.0, end_s=9.0,
                                      rom={"shoulder_elevation": rom}, angles=[])
                     for n in did.get(i, ("shoulder_flexion", "shoulder_abduction"))]
        content._CACHE.put(report_key(s), content.SessionReport.model_construct(
            rom={"shoulder_elevation": rom}, exercises=exercises))
    reported = [content.session_report(db, s).rom["shoulder_elevation"] for s in sessions[:3]]
    assert [(r.target_min, r.target_max) for r in reported] == [
        (0, 140), (0, 100), (None, None)]


def test_this_weeks_shortened_says_only_what_is_true_today(db, monkeypatch):
    # device-today's this_week.shortened tells the phone why the week asks fewer days
    # ("your program ends on Wednesday"); the week follows the version in force on its
    # Monday (the therapist's adherence rule). A program to end on Wednesday, extended
    # by the therapist on Thursday, is still followed: on Thursday it does not "end on
    # Wednesday", and the phone must not say so; nor, on Wednesday, that a program moved
    # on Tuesday to start that day "started on Friday" (its Monday version's start).
    from datetime import UTC, datetime
    from zoneinfo import ZoneInfo

    from armtrack.server import clock
    from armtrack.server.programs import adherence

    zone = ZoneInfo("Europe/Zurich")
    patient = add_patient(db, "Ending")
    monkeypatch.setattr(clock, "now", lambda: datetime(2026, 11, 20, 9, tzinfo=UTC))
    program = store.create_program(db, patient.id, ProgramIn(
        name="Until Wednesday", start_date=date(2026, 11, 23), end_date=date(2026, 12, 2),
        exercises=[ELBOW]), therapist_id=1)
    tuesday = adherence.this_week(db, patient.id, program, date(2026, 12, 1), zone)
    assert (tuesday["days_asked"], tuesday["shortened"]) == (
        3, {"starts_on": None, "ends_on": date(2026, 12, 2)})
    monkeypatch.setattr(clock, "now", lambda: datetime(2026, 12, 3, 9, tzinfo=UTC))
    store.change_program(db, program, PrescriptionIn(
        start_date=date(2026, 11, 23), exercises=[ELBOW]), therapist_id=1)
    thursday = date(2026, 12, 3)
    assert stream.device_today(db, patient, thursday) is not None  # still followed
    week = adherence.this_week(db, patient.id, program, thursday, zone)
    assert week["days_asked"] == 3  # the week's Monday version: Monday to Wednesday
    assert week["shortened"] is None, week
    monkeypatch.setattr(clock, "now", lambda: datetime(2026, 11, 27, 9, tzinfo=UTC))
    later = store.create_program(db, patient.id, ProgramIn(
        name="From Friday", start_date=date(2026, 12, 4), exercises=[ELBOW]), therapist_id=1)
    store.end_program(db, program)
    friday = adherence.this_week(db, patient.id, later, date(2026, 12, 4), zone)
    assert (friday["days_asked"], friday["shortened"]) == (
        3, {"starts_on": date(2026, 12, 4), "ends_on": None})
    monkeypatch.setattr(clock, "now", lambda: datetime(2026, 12, 1, 9, tzinfo=UTC))
    store.change_program(db, later, PrescriptionIn(
        start_date=date(2026, 12, 1), exercises=[ELBOW]), therapist_id=1)
    wednesday = date(2026, 12, 2)
    assert stream.device_today(db, patient, wednesday)["program"]["id"] == later.id
    week = adherence.this_week(db, patient.id, later, wednesday, zone)
    assert week["days_asked"] == 3 and week["shortened"] is None, week
