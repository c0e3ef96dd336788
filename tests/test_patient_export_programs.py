"""A patient's export ("everything held about the patient": their copy before an erasure,
or the file a therapist hands a colleague) left out what was prescribed and what the patient
said: no program, none of its versions, and none of the pain and effort ratings given after
the exercises — all stored, all the patient's. Now ``programs.json`` holds each program
with every version (its exercises) and the sessions that followed each, and
``sessions/<id>/ratings.json`` the ratings. A real server, a real kit stream naming the
program and carrying ratings (``server/emulator``), the zip read back."""

from __future__ import annotations

import asyncio
import io
import json
import zipfile
from datetime import UTC, date, datetime

from armtrack.server.emulator import KitEmulator
from server_support import server_fixture
from test_programs_followed import Planned, recording_of

server = server_fixture("export-programs", "alice")


def test_the_export_holds_the_programs_versions_and_the_patients_ratings(server):
    api = server.client("alice")
    patient = api.patient("Exported")
    token = api.device(patient["id"], "phone")["token"]
    exercise = {"exercise": "elbow_flexion", "sets": 1, "repetitions": 5, "days_per_week": 5}
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Elbow at home", "start_date": date.today().isoformat(),
        "exercises": [exercise]})
    assert made.status_code == 201, made.text
    program = made.json()
    changed = api.http.put(f"/api/programs/{program['id']}", json={
        "start_date": date.today().isoformat(), "note": "more repetitions",
        "exercises": [exercise | {"repetitions": 8}]})
    assert changed.status_code == 200, changed.text
    kit = KitEmulator(recording_of(Planned(datetime.now(UTC), {"elbow_flexion": [(3, 90.0)]}),
                                   seed=5), server.ws_url, token, speed=0, rows_per_message=50,
                      hello_extra={"extensions": ["programs/1", "effort-pain/1"],
                                   "program": "Elbow at home"},
                      ratings=[{"id": "r1", "exercise": "elbow_flexion", "t": 20.0,
                                "effort": 4.0, "pain": 3}])
    session = api.wait_processed(asyncio.run(kit.run()).session, timeout=240)["id"]

    answer = api.http.get(f"/api/patients/{patient['id']}/export")
    assert answer.status_code == 200, answer.text[:300]
    archive = zipfile.ZipFile(io.BytesIO(answer.content))
    names = archive.namelist()
    print("\n" + "\n".join(names))
    assert "programs.json" in names
    programs = json.loads(archive.read("programs.json"))
    print(json.dumps(programs, indent=1)[:1500])
    assert [p["program"]["name"] for p in programs] == ["Elbow at home"]
    versions = programs[0]["versions"]
    assert [v["number"] for v in versions] == [1, 2]
    assert [v["exercises"][0]["repetitions"] for v in versions] == [5, 8]
    assert programs[0]["sessions_followed"] == [{"session_id": session, "version": 2}]
    ratings = json.loads(archive.read(f"sessions/{session}/ratings.json"))
    print(ratings)
    assert [(r["exercise"], r["effort"], r["pain"]) for r in ratings] == [
        ("elbow_flexion", 4.0, 3)]
