"""The clinic's records on a real server: the clinic's settings and the therapist's name,
the patient's clinic number and date of birth (edited, listed with the last session),
every API time with its zone, and the target versions the migration keeps."""

from __future__ import annotations

import asyncio
from datetime import datetime

import pytest
import sqlalchemy as sa
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from server_support import ServerProcess


@pytest.fixture(scope="module")
def clinic_server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("clinic"), {
        "ARMTRACK_CLINIC_NAME": "Rehab Clinic Nord",
        "ARMTRACK_CLINIC_ADDRESS": "12 Quai des Chartrons, 33000 Bordeaux",
        "ARMTRACK_CLINIC_TIMEZONE": "Europe/Paris"})
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


def test_clinic_settings_and_the_therapists_full_name(clinic_server):
    alice = clinic_server.client("alice")
    assert alice.http.get("/api/clinic").json() == {
        "name": "Rehab Clinic Nord", "address": "12 Quai des Chartrons, 33000 Bordeaux",
        "time_zone": "Europe/Paris", "clock": "24h"}
    me = alice.http.get("/api/me").json()
    assert me["username"] == "alice" and me["full_name"] is None
    changed = alice.http.patch("/api/me", json={"full_name": "Dr Alice Martin"})
    assert changed.status_code == 200 and changed.json()["full_name"] == "Dr Alice Martin"
    assert alice.http.get("/api/me").json()["full_name"] == "Dr Alice Martin"
    assert alice.http.patch("/api/me", json={"full_name": "x" * 201}).status_code == 422
    import httpx
    assert httpx.get(clinic_server.url + "/api/clinic").status_code == 401


def test_an_unknown_clinic_time_zone_is_refused_by_name(tmp_path):
    done = ServerProcess(tmp_path, {"ARMTRACK_CLINIC_TIMEZONE": "Mars/Olympus"}).armtrack(
        "create-user", "x", "--password", "long enough")
    assert done.returncode != 0
    assert "Mars/Olympus" in done.stderr and "IANA" in done.stderr


def test_patient_identifiers_are_optional_edited_and_listed(clinic_server):
    alice = clinic_server.client("alice")
    plain = alice.patient("Plain Patient")
    assert plain["clinic_number"] is None and plain["date_of_birth"] is None
    made = alice.http.post("/api/patients", json={
        "name": "Marie Curie", "side": "left", "height_m": 1.6,
        "clinic_number": "BX-2291", "date_of_birth": "1967-11-07"})
    assert made.status_code == 201, made.text
    patient = made.json()
    assert (patient["clinic_number"], patient["date_of_birth"]) == ("BX-2291", "1967-11-07")
    bad = alice.http.post("/api/patients", json={
        "name": "x", "side": "left", "height_m": 1.6, "date_of_birth": "7/11/1967"})
    assert bad.status_code == 422 and "date_of_birth" in bad.text

    url = f"/api/patients/{patient['id']}"
    edited = alice.http.patch(url, json={"name": "Marie Skłodowska-Curie", "height_m": 1.62})
    assert edited.status_code == 200, edited.text
    assert edited.json()["name"] == "Marie Skłodowska-Curie"
    assert edited.json()["clinic_number"] == "BX-2291"  # left out: kept
    cleared = alice.http.patch(url, json={"clinic_number": None}).json()
    assert cleared["clinic_number"] is None and cleared["date_of_birth"] == "1967-11-07"
    assert alice.http.patch(url, json={"name": None}).status_code == 422
    assert alice.http.patch(url, json={"side": "both"}).status_code == 422
    assert alice.http.patch(url, json={"colour": "red"}).status_code == 422

    # the list carries the last session's start, with its zone
    token = alice.device(patient["id"])["token"]
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    stats = asyncio.run(KitEmulator(recording, clinic_server.ws_url, token, speed=0,
                                    rows_per_message=200).run())
    listed = {p["id"]: p for p in alice.http.get("/api/patients").json()}
    assert listed[plain["id"]]["last_session_at"] is None
    last = datetime.fromisoformat(listed[patient["id"]]["last_session_at"])
    session = alice.session(stats.session)
    assert last == datetime.fromisoformat(session["started_at"])


def test_a_date_of_birth_after_today_or_before_1900_is_refused_in_words(clinic_server):
    """Found on the add-patient form: a date of birth of 2030-01-01 (a typo for 1930, or
    2058 for 1958) was stored and printed on the patient's page and reports."""
    from datetime import date, timedelta

    alice = clinic_server.client("alice")
    tomorrow = (date.today() + timedelta(days=2)).isoformat()
    for when in (tomorrow, "1899-12-31"):
        bad = alice.http.post("/api/patients", json={
            "name": "Typo", "side": "left", "height_m": 1.6, "date_of_birth": when})
        print(bad.text)
        assert bad.status_code == 422, bad.text
        assert f"date of birth {when}" in bad.text and "Value error" not in bad.text
    patient = alice.patient("Born Well")
    edited = alice.http.patch(f"/api/patients/{patient['id']}",
                              json={"date_of_birth": tomorrow})
    assert edited.status_code == 422 and "after today" in edited.text
    assert alice.http.patch(f"/api/patients/{patient['id']}",
                            json={"date_of_birth": "1900-01-01"}).status_code == 200
    names = [p["name"] for p in alice.http.get("/api/patients").json()]
    assert "Typo" not in names


def test_every_api_time_carries_its_time_zone(clinic_server):
    """SQLite keeps no zone: every datetime the API sends must still carry one."""
    alice = clinic_server.client("alice")
    patient = alice.patient("Zoned")
    device = alice.device(patient["id"])
    alice.http.put(f"/api/patients/{patient['id']}/targets/elbow_flexion",
                   json={"min_deg": 0, "max_deg": 120})
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    stats = asyncio.run(KitEmulator(recording, clinic_server.ws_url, device["token"],
                                    speed=0, rows_per_message=200).run())
    alice.wait_processed(stats.session, timeout=120)
    times = {
        "patient.created_at": alice.http.get(f"/api/patients/{patient['id']}").json()[
            "created_at"],
        "device.created_at": alice.http.get(f"/api/patients/{patient['id']}/devices").json()[
            0]["created_at"],
        "session.started_at": alice.session(stats.session)["started_at"],
        "session.ended_at": alice.session(stats.session)["ended_at"],
        "target.updated_at": alice.http.get(f"/api/patients/{patient['id']}/targets").json()[
            0]["updated_at"],
        "history.set_at": alice.http.get(
            f"/api/patients/{patient['id']}/targets/history").json()[0]["set_at"],
        "report.started_at": alice.http.get(f"/api/sessions/{stats.session}/report").json()[
            "session"]["started_at"],
        "audit.at": alice.http.get("/api/audit").json()[0]["at"],
    }
    print(times)
    for name, text in times.items():
        assert text is not None, name
        assert datetime.fromisoformat(text).tzinfo is not None, (name, text)


def test_the_migration_keeps_todays_targets_as_their_first_version(tmp_path):
    from armtrack.server.db.engine import make_engine
    from armtrack.server.db.migrate import upgrade
    from armtrack.server.reports.targets import targets_at

    engine = make_engine(f"sqlite:///{tmp_path / 'm.db'}")
    upgrade(engine, "0004")
    with engine.begin() as connection:
        connection.exec_driver_sql(
            "INSERT INTO therapists (id, username, password_hash, created_at, is_admin) "
            "VALUES (1, 'a', 'x', '2026-01-01 00:00:00', 0)")
        connection.exec_driver_sql(
            "INSERT INTO patients (id, therapist_id, name, side, height_m, created_at) "
            "VALUES (1, 1, 'p', 'right', 1.7, '2026-01-01 00:00:00')")
        connection.exec_driver_sql(
            "INSERT INTO patient_targets (patient_id, angle, min_deg, max_deg, note, "
            "updated_at) VALUES (1, 'elbow_flexion', 0, 110, 'week 1', "
            "'2026-03-01 09:00:00')")
    upgrade(engine)
    from sqlalchemy.orm import Session
    with Session(engine) as db:
        before = targets_at(db, 1, datetime.fromisoformat("2026-02-28T09:00:00+00:00"))
        after = targets_at(db, 1, datetime.fromisoformat("2026-03-02T09:00:00+00:00"))
    assert before == {}
    assert (after["elbow_flexion"].max_deg, after["elbow_flexion"].note) == (110, "week 1")
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT clinic_number, date_of_birth FROM patients")
                                  ).one() == (None, None)


def _recording_text(start_time: str | None) -> bytes:
    from dataclasses import replace

    from armtrack.estimator.recording import format_recording
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    if start_time is not None:
        recording = replace(recording, metadata={**recording.metadata,
                                                 "start_time": start_time})
    return format_recording(recording)


def test_an_upload_is_dated_when_it_was_recorded(clinic_server):
    """docs/extensions/start-time.md: the start_time header dates the session; without
    it the upload time, labelled "uploaded"; a bad one is refused naming the header."""
    alice = clinic_server.client("alice")
    patient = alice.patient("Dated")

    def upload(text: bytes):
        return alice.http.post("/api/recordings", data={"patient_id": patient["id"]},
                               files={"file": ("home.csv", text, "text/csv")})

    dated = upload(_recording_text("2026-11-30T09:41:07+01:00"))
    assert dated.status_code == 201, dated.text
    session = dated.json()
    assert session["dated"] == "recorded"
    started = datetime.fromisoformat(session["started_at"])
    assert started == datetime.fromisoformat("2026-11-30T08:41:07+00:00")
    span = (datetime.fromisoformat(session["ended_at"]) - started).total_seconds()
    assert 5 < span < 120, span
    exported = alice.http.get(f"/api/sessions/{session['id']}/recording.csv").text
    assert "# start_time: 2026-11-30T09:41:07+01:00" in exported

    plain = upload(_recording_text(None)).json()
    assert plain["dated"] == "uploaded"
    assert (datetime.now(datetime.fromisoformat(plain["started_at"]).tzinfo)
            - datetime.fromisoformat(plain["started_at"])).total_seconds() < 300

    before = len(alice.http.get(f"/api/patients/{patient['id']}/sessions").json())
    for bad, words in (("2026-11-30T09:41:07", "no time zone"),
                       ("last tuesday", "not an ISO 8601"),
                       ("2999-01-01T00:00:00Z", "in the future")):
        refused = upload(_recording_text(bad))
        assert refused.status_code == 422, refused.text
        assert "start_time" in refused.json()["detail"] and words in refused.json()["detail"]
    after = len(alice.http.get(f"/api/patients/{patient['id']}/sessions").json())
    assert after == before  # nothing stored of a refused file
