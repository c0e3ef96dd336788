"""A trunk that swayed through the calibration poses (``trunk-swayed``) reaches the
therapist as the other calibration warnings do: the session's summary (its page lists
``quality.calibration_warnings``) and the report's quality warnings (JSON and PDF). Real
server."""

from __future__ import annotations

import re
import shutil
import subprocess

from armtrack.estimator.recording import format_recording
from test_estimation_hard_cases import random_sway_kit


def test_a_swaying_trunk_is_in_the_sessions_warnings(module_server):
    api = module_server.client("alice")
    recording = random_sway_kit(9).recording  # 9-axis, the upright 1.68° off, σ 0.78°
    patient = api.http.post("/api/patients", json={
        "name": "Swaying", "side": recording.side, "height_m": recording.height_m}).json()
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("sway.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    session = answer.json()
    assert session["processed"], session
    summary = api.http.get(f"/api/sessions/{session['id']}/summary").json()
    shown = [w for w in summary["quality"]["calibration_warnings"] if "trunk swayed" in w]
    print("summary:", shown)
    assert len(shown) == 1 and "back supported" in shown[0]
    known = re.search(r"known only to ±(\d+\.\d)°", shown[0])
    assert known and float(known.group(1)) > 1.0  # the 9-axis bar: 2σ over it
    report = api.http.get(f"/api/sessions/{session['id']}/report").json()
    assert shown[0] in report["quality"]["warnings"], report["quality"]["warnings"]
    if shutil.which("pdftotext") is None:
        return  # the PDF's text needs poppler-utils; the JSON above is what it prints
    pdf = api.http.get(f"/api/sessions/{session['id']}/report.pdf")
    assert pdf.status_code == 200
    text = subprocess.run(["pdftotext", "-", "-"], input=pdf.content, capture_output=True,
                          check=True).stdout.decode()
    print("PDF:", " ".join(line for line in text.splitlines() if "sway" in line))
    assert "trunk swayed" in " ".join(text.split())
