"""Discharge (docs/extensions/discharge.md) on a real server: a discharged patient stays with
every session and report, is listed as before unless the client asks to leave them out, and
their kit starts no new session (a refused hello and upload, in words) until readmitted."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime

import sqlalchemy as sa
from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from server_support import server_fixture
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

discharge_server = server_fixture("discharge", "alice", "bob")


def _hello(ws_url: str, token: str) -> tuple[dict, int | None]:
    """A kit's hello for a new session: (the server's first answer, the close code if the
    server closed the socket after it)."""

    async def run():
        async with connect(ws_url, additional_headers={"Authorization": f"Bearer {token}"}
                           ) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": ["forearm"],
                                      "rate_hz": 100, "nine_axis": False, "resume": None}))
            answer = json.loads(await ws.recv())
            code = None
            try:
                await asyncio.wait_for(ws.recv(), 5)
            except ConnectionClosed as closed:
                code = closed.rcvd.code if closed.rcvd else None
            except TimeoutError:
                pass
            return answer, code

    return asyncio.run(run())


def test_a_discharged_patient_keeps_their_records_and_their_kit_starts_nothing(
        discharge_server):
    alice = discharge_server.client("alice")
    bob = discharge_server.client("bob")
    patient = alice.patient("Dora Discharged")
    other = alice.patient("Ivan In-care")
    assert patient["discharged_at"] is None
    token = alice.device(patient["id"])["token"]
    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=1)).recording
    stats = asyncio.run(KitEmulator(recording, discharge_server.ws_url, token, speed=0,
                                    rows_per_message=200).run())
    alice.wait_processed(stats.session, timeout=120)
    url = f"/api/patients/{patient['id']}"

    # another therapist's patient: as if it did not exist
    assert bob.http.post(url + "/discharge").status_code == 404
    assert bob.http.post(url + "/readmit").status_code == 404

    before = datetime.now(UTC)
    answer = alice.http.post(url + "/discharge")
    assert answer.status_code == 200, answer.text
    discharged_at = datetime.fromisoformat(answer.json()["discharged_at"])
    print("discharged at", discharged_at)
    assert discharged_at.tzinfo is not None and discharged_at >= before.replace(microsecond=0)
    again = alice.http.post(url + "/discharge").json()  # a retry keeps the first date
    assert datetime.fromisoformat(again["discharged_at"]) == discharged_at
    assert datetime.fromisoformat(alice.http.get(url).json()["discharged_at"]) == discharged_at

    # the list answers as before unless asked: an existing client still sees everyone
    everyone = {p["id"]: p for p in alice.http.get("/api/patients").json()}
    assert set(everyone) == {patient["id"], other["id"]}
    assert everyone[patient["id"]]["discharged_at"] is not None
    assert everyone[other["id"]]["discharged_at"] is None
    in_care = [p["id"] for p in alice.http.get("/api/patients?discharged=false").json()]
    assert in_care == [other["id"]]
    gone = [p["id"] for p in alice.http.get("/api/patients?discharged=true").json()]
    assert gone == [patient["id"]]
    assert alice.http.get("/api/patients?discharged=maybe").status_code == 422

    # their records stay readable
    assert alice.http.get(url + "/sessions").json()[0]["id"] == stats.session
    assert alice.http.get(f"/api/sessions/{stats.session}/report").status_code == 200
    assert alice.http.get(f"/api/sessions/{stats.session}/recording.csv").status_code == 200
    assert alice.http.get(url + "/progress").status_code == 200

    # their kit is told (docs/extensions/device-today.md), and starts no new session:
    # the hello and an upload refused in words
    kit = {"Authorization": f"Bearer {token}"}
    today = alice.http.get("/api/device/today", headers=kit).json()
    assert today["discharged"] is True
    answer, code = _hello(discharge_server.ws_url, token)
    print("refused hello:", answer, code)
    assert answer["type"] == "error" and code == 4400
    assert "discharged by the therapist" in answer["reason"]
    upload = discharge_server.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",
                                  p=patient["id"])
    assert upload == [(1,)]  # nothing stored
    refused = alice.http.post("/api/recordings", headers={"Authorization": f"Bearer {token}"},
                              files={"file": ("home.csv", format_recording(recording),
                                              "text/csv")})
    print("refused upload:", refused.status_code, refused.text)
    assert refused.status_code == 403 and "discharged by the therapist" in refused.text
    assert len(alice.http.get(url + "/sessions").json()) == 1

    # readmitted: the kit starts sessions again
    back = alice.http.post(url + "/readmit")
    assert back.status_code == 200 and back.json()["discharged_at"] is None
    answer, code = _hello(discharge_server.ws_url, token)
    assert answer["type"] == "ready", answer
    assert alice.http.get("/api/device/today", headers=kit).json()["discharged"] is False
    assert {p["id"] for p in alice.http.get("/api/patients?discharged=false").json()} == {
        other["id"], patient["id"]}

    # audited as the patient's changes
    actions = [(e["action"], e["patient_id"]) for e in alice.http.get(
        f"/api/audit?patient_id={patient['id']}").json()]
    print(actions[:6])
    assert ("discharged", patient["id"]) in actions and ("readmitted", patient["id"]) in actions


def test_the_migration_leaves_every_patient_in_care(tmp_path):
    from armtrack.server.db.engine import make_engine
    from armtrack.server.db.migrate import upgrade

    engine = make_engine(f"sqlite:///{tmp_path / 'm.db'}")
    upgrade(engine, "0009")
    with engine.begin() as connection:
        connection.exec_driver_sql(
            "INSERT INTO therapists (id, username, password_hash, created_at, is_admin) "
            "VALUES (1, 'a', 'x', '2026-01-01 00:00:00', 0)")
        connection.exec_driver_sql(
            "INSERT INTO patients (id, therapist_id, name, side, height_m, created_at) "
            "VALUES (1, 1, 'p', 'right', 1.7, '2026-01-01 00:00:00')")
    upgrade(engine)
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT name, discharged_at FROM patients")
                                  ).one() == ("p", None)


def test_a_discharged_patient_needs_no_look(discharge_server):
    """``GET /api/flags`` lists the patients who need a look: one discharged with a program
    still running is flagged "no session for N days" ever after, though no session is
    expected of them any more. Discharged, they leave the flags; readmitted, they are back."""
    import datetime

    alice = discharge_server.client("alice")
    patient = alice.patient("Fay Flagged")
    started = datetime.date.today() - datetime.timedelta(days=10)
    answer = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Elbow", "start_date": started.isoformat(), "exercises": [
            {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 7}]})
    assert answer.status_code == 201, answer.text

    def flagged() -> list[str]:
        return [f["kind"] for row in alice.http.get("/api/flags").json()
                if row["patient_id"] == patient["id"] for f in row["flags"]]

    assert flagged() == ["no_session"]
    url = f"/api/patients/{patient['id']}"
    assert alice.http.post(url + "/discharge").status_code == 200
    print("discharged:", flagged())
    assert flagged() == []
    assert alice.http.post(url + "/readmit").status_code == 200
    assert flagged() == ["no_session"]


def test_the_admins_patient_list_says_who_is_discharged(discharge_server):
    """``GET /api/admin/patients`` (the admin's hand-over list) carries ``discharged_at``
    and takes ``discharged=false|true`` as ``GET /api/patients`` does; without it, every
    patient as before."""
    discharge_server.create_admin("root")
    alice, root = discharge_server.client("alice"), discharge_server.client("root")
    gone = alice.patient("Gus Gone")
    here = alice.patient("Hal Here")
    assert alice.http.post(f"/api/patients/{gone['id']}/discharge").status_code == 200

    def listed(**params) -> dict[int, str | None]:
        answer = root.http.get("/api/admin/patients", params={"limit": 500, **params})
        assert answer.status_code == 200, answer.text
        return {p["id"]: p["discharged_at"] for p in answer.json()
                if p["id"] in (gone["id"], here["id"])}

    every = listed()
    print("admin's list:", every)
    assert every[here["id"]] is None and every[gone["id"]] is not None
    assert set(listed(discharged="false")) == {here["id"]}
    assert set(listed(discharged="true")) == {gone["id"]}
