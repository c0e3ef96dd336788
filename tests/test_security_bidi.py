"""Direction controls in names ("Trojan Source"-style spoofing): U+202E and its kin make
a name show in another order than it is written ("Anna\\u202Eevil" shows "Annalive"), so
one patient could be made to look like another on the therapist's pages, reports and
exports. They are refused where a name comes in (422 naming the field and the
character; a kit's hello: error, close 4400), nothing stored; a name stored before the
rule is shown with the character written out ("[U+202E]"), on every route that reads it.
Real server."""

from __future__ import annotations

import asyncio
import json

import pytest
from server_support import ServerProcess
from test_input_bounds import hello_text, stream
from websockets.asyncio.client import connect

RLO = "\u202e"
ALL = ["\u202a", "\u202b", "\u202c", "\u202d", "\u202e", "\u2066", "\u2067", "\u2068",
       "\u2069", "\u200e", "\u200f", "\u061c"]


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("bidi"))
    server.create_user("alice")
    server.create_admin("root")
    server.start(timeout=120)
    yield server
    server.stop()


def refused(answer, field: str, char: str) -> None:
    print(answer.status_code, answer.text[:400])
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert any(e["loc"][-1] == field for e in detail), detail
    assert f"U+{ord(char):04X}" in answer.text and "direction" in answer.text, answer.text


@pytest.mark.parametrize("char", ALL, ids=[f"U+{ord(c):04X}" for c in ALL])
def test_a_patient_name_with_a_direction_control_is_refused(srv, char):
    api = srv.client("alice")
    before = api.http.get("/api/patients").json()
    refused(api.http.post("/api/patients", json={"name": f"Anna{char}evil", "side": "right",
                                                 "height_m": 1.7}), "name", char)
    assert api.http.get("/api/patients").json() == before  # nothing stored


def test_every_name_route_refuses_direction_controls(srv):
    api = srv.client("alice")
    patient = api.patient(name="Bidi routes")
    pid = patient["id"]
    refused(api.http.patch(f"/api/patients/{pid}", json={"name": f"Anna{RLO}x"}), "name", RLO)
    refused(api.http.patch(f"/api/patients/{pid}", json={"clinic_number": f"12{RLO}34"}),
            "clinic_number", RLO)
    assert api.http.get(f"/api/patients/{pid}").json()["name"] == "Bidi routes"
    refused(api.http.post(f"/api/patients/{pid}/devices", json={"name": f"kit{RLO}x"}),
            "name", RLO)
    assert api.http.get(f"/api/patients/{pid}/devices").json() == []
    refused(api.http.patch("/api/me", json={"full_name": f"Dr {RLO}x"}), "full_name", RLO)
    assert api.http.get("/api/me").json()["full_name"] is None
    program = {"name": f"Morning{RLO}x", "start_date": "2026-12-01",
               "exercises": [{"exercise": "elbow_flexion"}]}
    refused(api.http.post(f"/api/patients/{pid}/programs", json=program), "name", RLO)
    assert api.http.get(f"/api/patients/{pid}/programs").json() == []
    root = srv.client("root")
    refused(root.http.post("/api/admin/therapists", json={
        "username": "bob", "full_name": f"Bob{RLO}x", "password": "correct horse battery"}),
        "full_name", RLO)


def test_a_kit_hello_with_a_direction_control_in_its_device_name_is_refused(srv):
    api = srv.client("alice")
    patient = api.patient(name="Bidi kit")
    device = api.device(patient["id"])
    answers = asyncio.run(stream(srv.ws_url, device["token"],
                                 hello_text(json.dumps(f"phone{RLO}x")), [], 0))
    print(answers)
    assert answers[0]["type"] == "error", answers
    assert "device" in answers[0]["reason"] and "U+202E" in answers[0]["reason"], answers
    assert {"type": "closed", "code": 4400} in answers
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


def test_a_name_stored_before_the_rule_is_shown_with_the_character_written_out(srv):
    # a database from before: the names went in when they were still taken
    api = srv.client("alice")
    patient = api.patient(name="Old name")
    pid = patient["id"]
    device = api.device(pid, name="old kit")
    srv.sql("UPDATE patients SET name = :n, clinic_number = :c WHERE id = :i",
            n=f"Anna{RLO}evil", c=f"12{RLO}34", i=pid)
    srv.sql("UPDATE devices SET name = :n WHERE id = :i", n=f"kit{RLO}x", i=device["id"])
    srv.sql("UPDATE therapists SET full_name = :n WHERE username = 'alice'", n=f"Dr{RLO}x")
    shown = "Anna[U+202E]evil"
    listed = [p for p in api.http.get("/api/patients").json() if p["id"] == pid]
    assert listed[0]["name"] == shown, listed
    assert listed[0]["clinic_number"] == "12[U+202E]34", listed
    assert api.http.get(f"/api/patients/{pid}").json()["name"] == shown
    assert api.http.get(f"/api/patients/{pid}/devices").json()[0]["name"] == "kit[U+202E]x"
    assert api.http.get("/api/me").json()["full_name"] == "Dr[U+202E]x"
    for path in (f"/api/patients/{pid}/export", f"/api/patients/{pid}/progress.csv",
                 f"/api/patients/{pid}/progress", f"/api/patients/{pid}/progress.pdf"):
        answer = api.http.get(path)
        assert answer.status_code == 200, (path, answer.text[:300])
        assert RLO.encode() not in answer.content, path
        assert "\\u202e" not in answer.text.lower(), path
    assert shown in api.http.get(f"/api/patients/{pid}/progress").json()["patient_name"]
    # stored as it was (nothing rewritten behind the therapist's back) until they rename it
    assert srv.sql("SELECT name FROM patients WHERE id = :i", i=pid) == [(f"Anna{RLO}evil",)]
    answer = api.http.patch(f"/api/patients/{pid}", json={"name": "Anna Evil"})
    assert answer.status_code == 200, answer.text
    assert srv.sql("SELECT name FROM patients WHERE id = :i", i=pid) == [("Anna Evil",)]



def test_a_kits_device_name_kept_from_before_is_shown_with_the_character_written_out(srv):
    # a session's metadata (a hello's device, an uploaded file's header) from before
    api = srv.client("alice")
    patient = api.patient(name="Bidi metadata")
    device = api.device(patient["id"])
    live_path = f"/api/patients/{patient['id']}/live"

    async def session_with_samples() -> tuple[int, dict]:
        headers = {"Authorization": f"Bearer {device['token']}"}
        async with connect(srv.ws_url, additional_headers=headers) as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "phone",
                                      "side": "right", "sensors": ["upper_arm"],
                                      "rate_hz": 100, "nine_axis": False, "resume": None}))
            ready = json.loads(await asyncio.wait_for(ws.recv(), 30))
            assert ready["type"] == "ready", ready
            rows = [[i / 100, 0.0, 9.81, 0.0, 0.0, 0.0, 0.0, None, None, None]
                    for i in range(50)]
            await ws.send(json.dumps({"type": "samples", "seq": 0, "sensor": "upper_arm",
                                      "rows": rows}))
            while json.loads(await asyncio.wait_for(ws.recv(), 30))["type"] != "ack":
                pass
            srv.sql("UPDATE sessions SET metadata = :m WHERE id = :i",
                    m=json.dumps({"device": f"phone{RLO}x"}), i=ready["session"])
            live = (await asyncio.to_thread(api.http.get, live_path)).json()
            await ws.send(json.dumps({"type": "bye"}))
            return ready["session"], live

    sid, live = asyncio.run(session_with_samples())
    print(live["session"])
    assert live["session"]["device"] == "phone[U+202E]x"
    assert api.session(sid)["metadata"]["device"] == "phone[U+202E]x"
    answer = api.http.get(f"/api/sessions/{sid}/recording.csv")
    assert answer.status_code == 200, answer.text[:300]
    assert RLO.encode() not in answer.content and "phone[U+202E]x" in answer.text
