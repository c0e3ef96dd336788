"""``GET /api/flags`` for a therapist with many patients: ``PATIENTS`` patients, each with
a program and ``len(PAINS)`` estimated sessions (three streamed and estimated for real,
then copied row by row to the other patients, as a clinic's database would hold them).
The flags come from every session's report; the answer must stay right when an input
changes (a new session, a program ended) — at once, with no stale answer — and the time
of a call is printed (cold, then again).

A real server, real WebSockets (``server/emulator``), real processing, a real SQLite file.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from datetime import date

import pytest
from armtrack.estimator.recording import Mark
from armtrack.estimator.simulation import ImuErrors, SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from server_support import ServerProcess

PATIENTS = 200
PAINS = (2, 4, 6)  # one session each, in this order: pain rising
PROGRAM = {"exercises": [{"exercise": "elbow_flexion", "sets": 1, "repetitions": 4,
                          "days_per_week": 7}]}


def _recording(seed: int):
    config = SimulationConfig(exercise="elbow_flexion", sensors=("forearm",), rate_hz=50.0,
                              nine_axis=False, seed=seed, repetitions=4,
                              errors=ImuErrors(gyro_noise=0.01, acc_noise=0.1))
    sim = simulate(config)
    end = float(sim.recording.sensors["forearm"].t[-1]) - 0.5
    marks = (*sim.recording.marks, Mark(10.5, "exercise:elbow_flexion"),
             Mark(end, "end:exercise:elbow_flexion"))
    return replace(sim.recording, marks=tuple(sorted(marks, key=lambda m: m.t)))


def _stream(server, device: dict, pain: int, seed: int) -> int:
    ratings = [{"id": f"r{seed}", "exercise": "elbow_flexion", "t": 20.0, "effort": 3.0,
                "pain": pain}]
    kit = KitEmulator(_recording(seed), server.ws_url, device["token"], speed=0,
                      rows_per_message=50, hello_extra={"extensions": ["effort-pain/1"]},
                      ratings=ratings)
    return asyncio.run(kit.run()).session


def _copy_sessions(server, sessions: list[int], patients: list[int]) -> None:
    """Each of ``sessions`` (with its marks, estimates and ratings) again for each of
    ``patients``, in one transaction."""
    from sqlalchemy import MetaData, create_engine, select

    engine = create_engine(server.database_url)
    meta = MetaData()
    names = ("sessions", "marks", "estimate_blocks", "session_ratings")
    meta.reflect(engine, only=names)
    t = {name: meta.tables[name] for name in names}
    try:
        with engine.begin() as db:
            rows = {name: [dict(r._mapping) for r in db.execute(
                select(t[name]).where((t[name].c.id if name == "sessions"
                                       else t[name].c.session_id).in_(sessions)))]
                for name in t}
            for patient in patients:
                for session in rows["sessions"]:
                    new = db.execute(t["sessions"].insert().values(
                        {**{k: v for k, v in session.items() if k != "id"},
                         "patient_id": patient, "device_id": None})).inserted_primary_key[0]
                    for name in ("marks", "estimate_blocks", "session_ratings"):
                        children = [{**{k: v for k, v in r.items() if k != "id"},
                                     "session_id": new}
                                    for r in rows[name] if r["session_id"] == session["id"]]
                        if children:
                            db.execute(t[name].insert(), children)
    finally:
        engine.dispose()


@pytest.fixture(scope="module")
def clinic(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("flags_scale"))
    server.create_user("alice")
    server.start(timeout=180)
    try:
        api = server.client("alice")
        today = date.today().isoformat()
        patients, programs = [], []
        for i in range(PATIENTS):
            patient = api.patient(f"Patient {i:03d}")
            made = api.http.post(f"/api/patients/{patient['id']}/programs",
                                 json={"name": "Elbow", "start_date": today, **PROGRAM})
            assert made.status_code == 201, made.text
            patients.append(patient["id"])
            programs.append(made.json()["id"])
        device = api.device(patients[0], "phone")
        sessions = [_stream(server, device, pain, seed) for seed, pain in enumerate(PAINS)]
        for session in sessions:
            assert api.wait_processed(session, timeout=180)["processed"]
        _copy_sessions(server, sessions, patients[1:])
        yield server, api, patients, programs
    finally:
        server.stop()


def _flags(api) -> tuple[dict[int, list[tuple]], float]:
    start = time.perf_counter()
    answer = api.http.get("/api/flags")
    took = time.perf_counter() - start
    assert answer.status_code == 200, answer.text
    return ({p["patient_id"]: sorted((f["kind"], f["program_id"]) for f in p["flags"])
             for p in answer.json()}, took)


def test_flags_of_many_patients_follow_their_inputs_at_once(clinic):
    server, api, patients, programs = clinic
    first, cold = _flags(api)
    again, warm = _flags(api)
    print(f"\n/api/flags, {PATIENTS} patients × {len(PAINS)} sessions: first call "
          f"{cold:.2f} s, again {warm:.2f} s")
    assert first == again
    assert sorted(first) == sorted(patients)  # each one's pain rises: 2, 4, 6
    assert all(flags == [("pain_rising", programs[i])]
               for i, flags in enumerate(first[p] for p in patients))

    # a program ended: its flags go at once
    ended = api.http.post(f"/api/programs/{programs[5]}/end")
    assert ended.status_code == 200, ended.text
    now, took_ended = _flags(api)
    assert patients[5] not in now
    # a new session without pain: the pain no longer rises, at once (once estimated)
    device = api.device(patients[7], "phone")
    session = _stream(server, device, 0, seed=10)
    assert api.wait_processed(session, timeout=180)["processed"]
    now, took_new = _flags(api)
    print(f"after a program ended: {took_ended:.2f} s; after a new session: {took_new:.2f} s")
    assert patients[7] not in now
    assert {p: f for p, f in now.items()} == {
        p: f for p, f in first.items() if p not in (patients[5], patients[7])}
