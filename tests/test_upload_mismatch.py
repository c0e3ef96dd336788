"""An uploaded recording whose side or body height differs from the patient's record is
processed as the file says, and says so: the session's warnings (summary, report JSON)
name both values and what the therapist can do (issue 21, "warn, and let the therapist
choose"; the upload dialog's own check is tests/test_import_browser.py's). Real server."""

from __future__ import annotations

import dataclasses

from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate


def _upload(api, patient_id: int, height_m: float) -> dict:
    recording = simulate(SimulationConfig(exercise="elbow_flexion", seed=2,
                                          repetitions=2)).recording
    recording = dataclasses.replace(recording, height_m=height_m)
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient_id)},
                           files={"file": ("elbow.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    session = answer.json()
    assert session["processed"], session
    return session


def test_a_file_taller_than_the_record_is_processed_with_a_warning(module_server):
    api = module_server.client("alice")
    patient = api.http.post("/api/patients", json={
        "name": "Record 1.68", "side": "right", "height_m": 1.68}).json()
    session = _upload(api, patient["id"], 1.80)
    summary = api.http.get(f"/api/sessions/{session['id']}/summary").json()
    words = " ".join(summary["quality"]["calibration_warnings"])
    print("warning:", words)
    assert "1.80 m" in words and "1.68 m" in words and "processed as the file says" in words
    report = api.http.get(f"/api/sessions/{session['id']}/report").json()
    warnings = report["quality"]["warnings"]
    assert any("1.68 m" in w for w in warnings), warnings


def test_a_file_that_agrees_with_the_record_has_no_such_warning(module_server):
    api = module_server.client("alice")
    patient = api.http.post("/api/patients", json={
        "name": "Record 1.75", "side": "right", "height_m": 1.75}).json()
    session = _upload(api, patient["id"], 1.75)
    summary = api.http.get(f"/api/sessions/{session['id']}/summary").json()
    assert not any("patient's record" in w for w in summary["quality"]["calibration_warnings"])
