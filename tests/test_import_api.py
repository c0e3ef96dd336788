"""Vendor files through the API on a real server: look inside before importing
(sensors, rates, durations, suggestions, a calibration proposal, side/height mismatch),
import with a sensor map, follow the processing at the progress route; damaged files
refused naming file and line with nothing stored; the spec's single ``file`` still works."""

import json
import time
from functools import cache

import httpx
import pytest
from armtrack.estimator.recording import format_recording, parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from importer_layouts import SIM_FIELD_UT, xsens_dot_csv

SENSORS = ("upper_arm", "forearm", "hand")


@cache
def sim():
    return simulate(SimulationConfig(rate_hz=60.0, repetitions=2, seed=5))


def dot_uploads(rec=None):
    rec = rec or sim().recording
    names = {"upper_arm": "Right Upper Arm_D422CD0011A2.csv",
             "forearm": "forearm_D422CD0011B7.csv", "hand": "hand_D422CD0011C3.csv"}
    return [("files", (names[s], xsens_dot_csv(rec.sensors[s], names[s].split("_")[0]),
                       "text/csv")) for s in SENSORS], names


@pytest.fixture(scope="module")
def alice(module_server):
    return module_server.client("alice")


def sessions_of(module_server, patient_id):
    return module_server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                             p=patient_id)[0][0]


def test_inspect_lists_sensors_suggests_segments_and_proposes_poses(alice):
    patient = alice.patient("Dora", side="right", height_m=1.75)
    files, names = dot_uploads()
    answer = alice.http.post("/api/recordings/inspect", data={"patient_id": patient["id"]},
                             files=files)
    assert answer.status_code == 200, answer.text
    body = answer.json()
    print(json.dumps(body, indent=1)[:1500])
    found = {f["name"]: f for f in body["files"]}
    for sensor, name in names.items():
        (s,) = found[name]["sensors"]
        assert found[name]["format"] == "xsens-dot"
        assert s["rate_hz"] == pytest.approx(60.0, rel=1e-3)
        assert s["duration_s"] == pytest.approx(float(sim().recording.sensors[sensor].t[-1]),
                                                abs=0.02)
        assert s["suggested"] == sensor
    assert body["proposal"].startswith("npose ") and "tpose" in body["proposal"]
    # an armtrack recording of the other side and another height: said before processing
    rec = sim().recording
    from dataclasses import replace

    left = replace(rec, side="left", height_m=1.62)
    answer = alice.http.post("/api/recordings/inspect", data={"patient_id": patient["id"]},
                             files=[("files", ("left.csv", format_recording(left), "text/csv"))])
    (f,) = answer.json()["files"]
    assert f["format"] == "armtrack" and f["side"] == "left"
    assert f["mismatch"] == [
        "the file records the left arm; right is the patient's treated arm on record",
        "the file's body height is 1.62 m; the patient's record says 1.75 m (segment "
        "lengths follow the height)"]


def test_import_with_a_sensor_map_and_poll_the_progress(module_server, alice):
    patient = alice.patient("Emil", side="right", height_m=1.75)
    files, names = dot_uploads()
    answer = alice.http.post("/api/recordings", files=files, data={
        "patient_id": patient["id"], "sensors": json.dumps(names),
        "calibration": "npose 0.5 3.0; tpose 5.5 8.0", "wait": "false",
        "options": json.dumps({"field_ut": SIM_FIELD_UT})})
    assert answer.status_code == 202, answer.text
    session = answer.json()
    assert answer.headers["location"] == f"/api/recordings/{session['id']}/progress"
    assert session["sensors"] == list(SENSORS) and session["source"] == "upload"
    states = []
    for _ in range(600):
        progress = alice.http.get(answer.headers["location"]).json()
        states.append(progress["state"])
        if progress["state"] != "processing":
            break
        time.sleep(0.1)
    print("progress states:", states[0], "…", states[-1], f"({len(states)} polls)")
    assert progress["state"] == "done" and progress["processed"]
    assert alice.http.get(f"/api/sessions/{session['id']}").json()["processed"]
    exported = alice.http.get(f"/api/sessions/{session['id']}/recording.csv").content
    back = parse_recording(exported)
    assert back.side == "right" and back.height_m == 1.75
    assert [(p.name, p.start, p.end) for p in back.calibration] == [
        ("npose", 0.5, 3.0), ("tpose", 5.5, 8.0)]
    assert back.metadata["import_format"] == "xsens-dot"
    assert abs(back.sensors["forearm"].t[-1] - sim().recording.sensors["forearm"].t[-1]) < 1e-6


def test_damaged_file_refused_naming_file_and_line_nothing_stored(module_server, alice):
    patient = alice.patient("Fay", side="right", height_m=1.75)
    files, names = dot_uploads()
    name, data, kind = files[1][1]
    files[1] = ("files", (name, data[:-25], kind))  # truncated
    answer = alice.http.post("/api/recordings", files=files, data={
        "patient_id": patient["id"], "sensors": json.dumps(names)})
    assert answer.status_code == 422
    detail = answer.json()["detail"]
    print(detail)
    assert detail.startswith(f"{name}, line ") and "truncated" in detail
    assert sessions_of(module_server, patient["id"]) == 0
    # a side that differs from the patient's record: refused before anything is stored
    files, names = dot_uploads()
    answer = alice.http.post("/api/recordings", files=files, data={
        "patient_id": patient["id"], "sensors": json.dumps(names), "side": "left"})
    assert answer.status_code == 409
    assert "left arm; right is the patient's" in answer.json()["detail"]
    assert sessions_of(module_server, patient["id"]) == 0


def test_single_recording_file_still_works_and_a_kit_follows_its_own_upload(module_server,
                                                                              alice):
    patient = alice.patient("Gus", side="right", height_m=1.75)
    other = alice.patient("Hal", side="right", height_m=1.75)
    token = alice.device(patient["id"])["token"]
    kit = httpx.Client(base_url=module_server.url, timeout=120,
                       headers={"Authorization": f"Bearer {token}"})
    data = format_recording(sim().recording)
    answer = kit.post("/api/recordings", files={"file": ("r.csv", data)})
    assert answer.status_code == 201 and answer.json()["processed"]
    mine = answer.json()["id"]
    assert kit.get(f"/api/recordings/{mine}/progress").json()["state"] == "done"
    theirs = alice.http.post("/api/recordings", data={"patient_id": other["id"]},
                             files={"file": ("r.csv", data)}).json()["id"]
    assert kit.get(f"/api/recordings/{theirs}/progress").status_code == 404
    both = kit.post("/api/recordings", files={"file": ("r.csv", data)},
                    data={"sensors": "{}"}, )
    assert both.status_code == 201  # sensors without files is ignored with file
    neither = kit.post("/api/recordings", data={"wait": "true"})
    assert neither.status_code == 422
