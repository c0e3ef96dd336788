"""Issue 17, a clinic admin's reach, on a real server: an admin holds no patients — they
cannot give one to themself (nor to another admin) to read it, cannot add one, and a
patient the database says is theirs (made before this rule) is 404 to them like anyone
else's (item 5), an upload's progress and the flags too; an admin cannot make an account named
``demo``, the name ``armtrack serve`` refuses to start with (low)."""

from __future__ import annotations

import asyncio

import pytest
from server_support import PASSWORD, ServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed


@pytest.fixture(scope="module")
def clinic(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("clinic"))
    server.create_user("alice")
    for admin in ("root", "root2"):
        done = server.armtrack("create-user", admin, "--admin", "--password", PASSWORD)
        assert done.returncode == 0, done.stderr
    server.start()
    yield server
    server.stop()


def ids(api) -> dict[str, int]:
    return {t["username"]: t["id"] for t in api.http.get("/api/admin/therapists").json()}


async def live_outcome(server, token: str, patient_id: int) -> str:
    url = f"ws://127.0.0.1:{server.port}/ws/live?patient={patient_id}"
    try:
        async with connect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            await asyncio.wait_for(ws.recv(), 2)
    except ConnectionClosed as exc:
        return str(exc.rcvd.code if exc.rcvd else None)
    except TimeoutError:
        return "open"
    return "message"


def test_an_admin_cannot_take_a_patient_to_read_its_data(clinic):
    alice, root = clinic.client("alice"), clinic.client("root")
    patient = alice.patient("Private Person")
    therapists = ids(root)
    for admin in ("root", "root2"):  # not to themself, not to another admin
        answer = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                                json={"therapist_id": therapists[admin]})
        assert answer.status_code == 409, answer.text
        assert "clinic admin" in answer.json()["detail"]
    assert alice.http.get(f"/api/patients/{patient['id']}").status_code == 200  # still hers
    assert root.http.post("/api/patients", json={"name": "Mine", "side": "left",
                                                 "height_m": 1.7}).status_code == 403
    # a patient the database gives an admin (made before the rule) is still out of reach
    clinic.sql("UPDATE patients SET therapist_id = :admin WHERE id = :id",
               admin=therapists["root"], id=patient["id"])
    for path in (f"/api/patients/{patient['id']}", f"/api/patients/{patient['id']}/sessions",
                 f"/api/patients/{patient['id']}/export"):
        assert root.http.get(path).status_code == 404, path
    assert root.http.get("/api/patients").json() == []
    assert root.http.post("/api/viewer", json={"patient_id": patient["id"]}
                          ).status_code == 404
    assert asyncio.run(live_outcome(clinic, root.token, patient["id"])) == "4404"
    # admins see who holds whom, to reassign: that list names patients and whether their
    # care ended (docs/extensions/discharge.md), nothing clinical
    listed = root.http.get("/api/admin/patients").json()
    assert {"id", "name", "therapist_id", "discharged_at"} == set(listed[0])
    back = root.http.post(f"/api/admin/patients/{patient['id']}/reassign",
                          json={"therapist_id": therapists["alice"]})
    assert back.status_code == 200, back.text


def test_an_admin_cannot_make_the_demo_account(clinic):
    root = clinic.client("root")
    for name in ("demo", "Demo"):
        answer = root.http.post("/api/admin/therapists", json={"username": name,
                                                              "password": PASSWORD})
        assert answer.status_code == 422, answer.text
        assert "armtrack demo" in answer.text
    assert "demo" not in {n.lower() for n in ids(root)}


def test_an_uploads_progress_is_404_to_an_admin_the_database_gives_the_patient(clinic):
    """``GET /api/recordings/{id}/progress`` compared the patient's therapist id with the
    caller's and so answered an admin holding a patient made before the rule (state,
    samples, processing error): every other route of the patient was 404 to them."""
    from armtrack.estimator.recording import format_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    alice, root = clinic.client("alice"), clinic.client("root")
    patient = alice.patient("Uploaded Person")
    recording = simulate(SimulationConfig(exercise="elbow_flexion", sensors=("forearm",),
                                          seed=2, repetitions=1)).recording
    answer = alice.http.post("/api/recordings", data={"patient_id": patient["id"]},
                             files={"file": ("r.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    session_id = answer.json()["id"]
    assert alice.http.get(f"/api/recordings/{session_id}/progress").status_code == 200
    clinic.sql("UPDATE patients SET therapist_id = :admin WHERE id = :id",
               admin=ids(root)["root"], id=patient["id"])
    answer = root.http.get(f"/api/recordings/{session_id}/progress")
    print(answer.status_code, answer.text)
    assert answer.status_code == 404, answer.text
    assert answer.json() == root.http.get("/api/recordings/999999/progress").json() | {
        "detail": f"no uploaded session {session_id}"}


def test_the_flags_say_nothing_to_an_admin_the_database_gives_a_patient(clinic):
    """``GET /api/flags`` listed the patients whose row names the caller, admin or not:
    an admin holding a patient made before the rule read that patient's flags (the
    program, no session for N days, each exercise's falling range, rising pain with
    their figures) while every route of the patient was 404 to them."""
    import datetime

    alice, root = clinic.client("alice"), clinic.client("root")
    patient = alice.patient("Flagged Person")
    started = datetime.date.today() - datetime.timedelta(days=10)
    answer = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Elbow", "start_date": started.isoformat(), "exercises": [
            {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10,
             "days_per_week": 7}]})
    assert answer.status_code == 201, answer.text
    flagged = [f for f in alice.http.get("/api/flags").json()
               if f["patient_id"] == patient["id"]]
    assert flagged and flagged[0]["flags"][0]["kind"] == "no_session", flagged
    clinic.sql("UPDATE patients SET therapist_id = :admin WHERE id = :id",
               admin=ids(root)["root"], id=patient["id"])
    assert root.http.get(f"/api/patients/{patient['id']}").status_code == 404
    answer = root.http.get("/api/flags")
    print(answer.status_code, answer.text[:300])
    assert answer.status_code == 200 and answer.json() == [], answer.text


def test_an_admin_cannot_make_a_reset_code_for_an_admin(clinic):
    """An admin could make a one-time reset code for another admin (or themself): whoever
    holds it chooses that admin's password and acts in their name, so that the audit log
    can no longer tell the two apart — and another admin gains no right by it that they
    lack. Refused now (403) in words that say what to do instead; nothing made, the
    other admin's password unchanged. A therapist's reset is as before."""
    import httpx

    root = clinic.client("root")
    therapists = ids(root)
    for admin in ("root2", "root"):
        answer = root.http.post(f"/api/admin/therapists/{therapists[admin]}/reset")
        print(f"\nreset code for {admin}: {answer.status_code} {answer.text}")
        assert answer.status_code == 403, answer.text
        detail = answer.json()["detail"]
        assert "clinic admin" in detail and "account page" in detail
        assert "armtrack create-user" in detail
    made = clinic.sql("SELECT count(*) FROM password_resets WHERE therapist_id IN (:a, :b)",
                      a=therapists["root"], b=therapists["root2"])[0][0]
    assert made == 0
    assert httpx.post(clinic.url + "/api/auth/token", data={
        "username": "root2", "password": PASSWORD}).status_code == 200
    answer = root.http.post(f"/api/admin/therapists/{therapists['alice']}/reset")
    assert answer.status_code == 200 and answer.json()["reset_token"].startswith("rt_")


def test_a_reset_code_made_for_an_admin_before_the_rule_sets_nothing(clinic):
    """The rule above is kept where the code is used too: a code made for an admin before
    it (an upgrade within the code's lifetime, ``ARMTRACK_RESET_TOKEN_HOURS``) would still
    let its holder choose that admin's password. ``POST /api/auth/reset`` with it is 403
    in words, the code stays unused, the admin's password and sign-ins unchanged."""
    from datetime import UTC, datetime, timedelta

    import httpx
    from armtrack.server.auth import new_token
    from armtrack.server.db import models
    from sqlalchemy import create_engine
    from sqlalchemy.orm import Session

    root = clinic.client("root")
    therapists = ids(root)
    token, digest = new_token("rt_")
    engine = create_engine(clinic.database_url)
    try:
        with Session(engine) as db:  # as the old server made it
            db.add(models.PasswordReset(therapist_id=therapists["root2"], token_hash=digest,
                                        issued_by=therapists["root"],
                                        expires_at=datetime.now(UTC) + timedelta(hours=24)))
            db.commit()
    finally:
        engine.dispose()
    signed_in = clinic.client("root2")
    answer = httpx.post(clinic.url + "/api/auth/reset", json={"new_password": "chosen-by-holder"},
                        headers={"Authorization": f"Bearer {token}"})
    print(f"\nreset with a code made for an admin: {answer.status_code} {answer.text}")
    assert answer.status_code == 403, answer.text
    assert "clinic admin" in answer.json()["detail"]
    used = clinic.sql("SELECT used_at FROM password_resets WHERE token_hash = :h", h=digest)
    assert used == [(None,)]
    assert httpx.post(clinic.url + "/api/auth/token", data={
        "username": "root2", "password": "chosen-by-holder"}).status_code == 401
    assert httpx.post(clinic.url + "/api/auth/token", data={
        "username": "root2", "password": PASSWORD}).status_code == 200
    assert signed_in.http.get("/api/admin/therapists").status_code == 200
