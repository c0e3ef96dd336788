"""The report's forms on a real server: CSV, PDF (rendered to PNG with ``pdftoppm``),
OpenSim ``.mot`` and ``.sto``, FHIR R4 (validated with ``fhir.resources``), exercises from
marks, and a schemathesis run over the reports' part of the OpenAPI document."""

from __future__ import annotations

import csv
import dataclasses
import io
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from armtrack.estimator.recording import format_recording, read_recording
from armtrack.estimator.recording.model import Mark

RECORDINGS = ("elbow_6axis", "left_reach_50hz", "shoulder_abduction")


@pytest.fixture(scope="module")
def alice(module_server):
    return module_server.client("alice")


def upload(api, patient_id, name, data):
    answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                           files={"file": (name, data, "text/csv")})
    assert answer.status_code == 201, answer.text
    return answer.json()


@pytest.fixture(scope="module")
def sessions(alice, recordings):
    """name → (session, recording), uploaded (the shared files where present, else the
    stand-ins: tests/recording_sets.py)."""
    out = {}
    for name in RECORDINGS:
        path = recordings.path(name)
        recording = read_recording(path)
        patient = alice.patient(name, recording.side, recording.height_m or 1.75)
        if name == "left_reach_50hz":  # a target in force when the session is recorded
            alice.http.put(f"/api/patients/{patient['id']}/targets/shoulder_flexion",
                           json={"min_deg": 0, "max_deg": 120, "note": "week 2"})
        out[name] = (upload(alice, patient["id"], path.name, path.read_bytes()), recording)
    return out


def get(alice, path, media=None):
    answer = alice.http.get(path)
    assert answer.status_code == 200, (path, answer.text[:500])
    if media:
        assert answer.headers["content-type"].startswith(media), answer.headers
        assert "attachment" in answer.headers["content-disposition"]
    return answer


def test_summary_csv_has_a_row_per_angle_and_exercise(alice, sessions, recordings):
    session, _ = sessions["elbow_6axis"]
    report = get(alice, f"/api/sessions/{session['id']}/report").json()
    text = get(alice, f"/api/sessions/{session['id']}/report.csv", "text/csv").text
    rows = list(csv.DictReader(io.StringIO(text)))
    whole = {r["angle"]: r for r in rows if r["scope"] == "session"}
    assert set(whole) == set(report["rom"]) == {"elbow_flexion", "wrist_flexion"}
    for angle, rom in report["rom"].items():
        assert float(whole[angle]["range"]) == rom["range"]
    expected = recordings.facts["elbow_6axis"].counts()  # README: 7 and 6
    assert {k: int(whole[k]["repetitions"]) for k in expected} == expected
    per_exercise = [r for r in rows if r["scope"] != "session"]
    assert sum(int(r["repetitions"]) for r in per_exercise) == sum(expected.values())
    print(text)


def test_pdf_renders_four_pages(alice, sessions, tmp_path):
    session, _ = sessions["left_reach_50hz"]
    alice.http.put(f"/api/patients/{session['patient_id']}/targets/shoulder_flexion",
                   json={"min_deg": 0, "max_deg": 120})
    pdf = get(alice, f"/api/sessions/{session['id']}/report.pdf", "application/pdf").content
    assert pdf.startswith(b"%PDF-")
    if shutil.which("pdftoppm") is None:
        pytest.skip("pdftoppm (Debian poppler-utils, installed by .ci/install) is missing")
    (tmp_path / "report.pdf").write_bytes(pdf)
    print(f"PDF: {tmp_path / 'report.pdf'} ({len(pdf)} bytes)")
    subprocess.run(["pdftoppm", "-png", "-r", "60", str(tmp_path / "report.pdf"),
                    str(tmp_path / "page")], check=True, timeout=120)
    pages = sorted(tmp_path.glob("page-*.png"))
    assert len(pages) == 4, pages  # summary, details, curves, repetitions + appendix
    from matplotlib.image import imread

    for page in pages:
        image = imread(page)
        assert image.shape[0] > image.shape[1] > 400  # A4 portrait at 60 dpi
        ink = float(np.mean(np.any(image[..., :3] < 0.9, axis=-1)))
        print(f"{page}: {image.shape[1]}×{image.shape[0]} px, {100 * ink:.1f}% ink")
        assert 0.01 < ink < 0.6  # drawn on, not blank and not black


def test_mot_of_a_kit_measuring_some_angles_keeps_every_coordinate(alice):
    """Found by the whole-API fuzzing: a forearm-only kit's session (its reports hold the
    measured angles only) made ``report.mot`` a 500 (KeyError 'shoulder_flexion'). The
    coordinates the kit does not measure keep the spec's 0, as in the angles CSV."""
    from armtrack.estimator.simulation import SimulationConfig, simulate

    recording = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=2, seed=3,
                                          sensors=("forearm",), nine_axis=False)).recording
    patient = alice.patient("Forearm only")
    session = upload(alice, patient["id"], "forearm.csv", format_recording(recording))
    alice.wait_processed(session["id"])
    text = get(alice, f"/api/sessions/{session['id']}/report.mot", "text/plain").text
    body = text.split("endheader\n")[1]
    columns = body.splitlines()[0].split("\t")
    values = np.loadtxt(io.StringIO(body), skiprows=1)
    assert len(columns) == 8 and values.shape[1] == 8
    col = {c: values[:, i] for i, c in enumerate(columns)}
    assert np.all(col["arm_flex_r"] == 0) and np.all(col["arm_add_r"] == 0)
    assert np.ptp(col["elbow_flex_r"]) > 90  # two flexions to 120°


def test_mot_has_rajagopal_coordinates_in_degrees(alice, sessions, recordings):
    for name, side in (("shoulder_abduction", "r"), ("left_reach_50hz", "l")):
        session, _ = sessions[name]
        text = get(alice, f"/api/sessions/{session['id']}/report.mot", "text/plain").text
        head, body = text.split("endheader\n")
        header = dict(line.split("=", 1) for line in head.splitlines()[1:])
        assert header["inDegrees"] == "yes" and header["version"] == "1"
        columns = body.splitlines()[0].split("\t")
        assert columns == ["time", *(f"{c}_{side}" for c in (
            "arm_flex", "arm_add", "arm_rot", "elbow_flex", "pro_sup", "wrist_flex",
            "wrist_dev"))]
        values = np.loadtxt(io.StringIO(body), skiprows=1)
        assert values.shape == (int(header["nRows"]), int(header["nColumns"]))
        assert np.all(np.diff(values[:, 0]) > 0)
        exercise = values[:, 0] >= 10.5  # after the calibration (T-pose: 90° abduction)
        col = {c: values[exercise, i] for i, c in enumerate(columns)}
        assert np.min(values[~exercise, 2]) == pytest.approx(-90, abs=1.5)  # the T-pose
        extremes = recordings.facts[name].extremes
        if name == "shoulder_abduction":  # abduction to 80°: adduction to −80°
            top = extremes["shoulder_abduction"][1]
            assert np.min(col[f"arm_add_{side}"]) == pytest.approx(-top, abs=1.5)
            assert np.max(col[f"arm_add_{side}"]) < 12  # the N-pose, calibration, rest
        else:  # left: flexion to 80°, elbow to 70°, same signs as on the right
            assert np.max(col[f"arm_flex_{side}"]) == pytest.approx(
                extremes["shoulder_flexion"][1], abs=1.5)
            assert np.max(col[f"elbow_flex_{side}"]) == pytest.approx(
                extremes["elbow_flexion"][1], abs=1.5)


def test_sto_is_an_opensense_orientation_table(alice, sessions):
    session, recording = sessions["left_reach_50hz"]
    text = get(alice, f"/api/sessions/{session['id']}/report.sto", "text/plain").text
    head, body = text.split("endheader\n")
    header = dict(line.split("=", 1) for line in head.splitlines())
    assert header["DataType"] == "Quaternion"
    assert float(header["DataRate"]) == pytest.approx(50, rel=0.01)
    lines = body.splitlines()
    columns = lines[0].split("\t")
    bodies = {"upper_arm": "humerus_l_imu", "forearm": "radius_l_imu", "hand": "hand_l_imu",
              "trunk": "torso_imu"}
    assert columns == ["time", *(bodies[s] for s in ("trunk", "upper_arm", "forearm", "hand")
                                 if s in recording.sensors)]
    for line in lines[1:: max(1, len(lines) // 50)]:
        cells = line.split("\t")
        for cell in cells[1:]:
            q = np.array([float(x) for x in cell.split(",")])
            assert q.shape == (4,) and np.linalg.norm(q) == pytest.approx(1, abs=1e-5)


def test_fhir_bundle_validates_as_r4(alice, sessions):
    from fhir.resources.R4B.bundle import Bundle
    from fhir.resources.R4B.diagnosticreport import DiagnosticReport
    from fhir.resources.R4B.observation import Observation

    session, _ = sessions["left_reach_50hz"]
    report = get(alice, f"/api/sessions/{session['id']}/report").json()
    answer = get(alice, f"/api/sessions/{session['id']}/report.fhir.json",
                 "application/fhir+json")
    bundle = Bundle.model_validate(answer.json())  # raises on an invalid resource
    resources = [e.resource for e in bundle.entry]
    reports = [r for r in resources if isinstance(r, DiagnosticReport)]
    observations = [r for r in resources if isinstance(r, Observation)]
    assert len(reports) == 1 and len(observations) == len(report["rom"])
    full_urls = {e.fullUrl for e in bundle.entry}
    assert {r.reference for r in reports[0].result} <= full_urls
    by_angle = {o.note[0].text.split()[2].rstrip(",;"): o for o in observations}
    for angle, rom in report["rom"].items():
        o = by_angle[angle]
        assert (o.code.coding[0].system, o.code.coding[0].code) == (
            "http://snomed.info/sct", "364564000")
        assert o.valueQuantity.code == "deg" and o.valueQuantity.system == \
            "http://unitsofmeasure.org"
        assert float(o.valueQuantity.value) == rom["range"]
        assert o.bodySite.coding[0].code.endswith(":272741003=7771000")  # left
        assert o.bodySite.text.startswith("left ")
        normal = o.referenceRange[0]
        assert float(normal.high.value) == rom["normal_max"] - rom["normal_min"]
        assert [float(c.valueQuantity.value) for c in o.component[:2]] == [rom["min"],
                                                                           rom["max"]]
    target = by_angle["shoulder_flexion"].referenceRange
    assert target[-1].type.coding[0].code == "treatment"  # in force when recorded
    print(answer.text[:1500])


def test_exercises_come_from_marks_when_the_file_has_them(alice, sessions, recordings):
    """elbow_6axis with its detected exercises' span marked as one: the same repetitions,
    now from the marks. (The shared file's elbow and wrist sets overlap: one exercise
    detected; the stand-in's follow each other: two.)"""
    session, recording = sessions["elbow_6axis"]
    detected = get(alice, f"/api/sessions/{session['id']}/report").json()["exercises"]
    assert len(detected) == (1 if recordings.source == "shared" else 2), detected
    a, b = detected[0]["start_s"], detected[-1]["end_s"]
    marks = (Mark(a - 0.3, "exercise:curls"), Mark(b + 0.3, "end:exercise:curls"))
    marked = format_recording(dataclasses.replace(recording, marks=marks))
    new = upload(alice, session["patient_id"], "marked.csv", marked)
    report = get(alice, f"/api/sessions/{new['id']}/report").json()
    (exercise,) = report["exercises"]
    assert exercise["source"] == "marks" and exercise["name"] == "curls"
    assert {x["angle"]: x["repetitions"] for x in exercise["angles"]} == (
        recordings.facts["elbow_6axis"].counts())  # README: 7 and 6
    assert set(exercise["rom"]) == {"elbow_flexion", "wrist_flexion"}


def test_schemathesis_finds_no_server_error_or_schema_violation(module_server, alice,
                                                                sessions, tmp_path):
    """Property-based run of the reports' routes (reports, progress, targets) from
    /openapi.json, signed in as a therapist who owns sessions 1…3 and patients 1…3, so
    many generated ids hit real data. Limited examples keep it to a minute or so."""
    if shutil.which("st", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("schemathesis (the test extra) is not installed")
    st = str(Path(sys.executable).parent / "st")
    done = subprocess.run(
        [st, "run", f"{module_server.url}/openapi.json",
         "-H", f"Authorization: Bearer {alice.token}",
         "--include-path-regex", r"/(report|progress|targets)",
         "--checks", "not_a_server_error,response_schema_conformance,"
                     "content_type_conformance,status_code_conformance",
         "--max-examples", "12", "--seed", "1", "--request-timeout", "60",
         "--phases", "examples,coverage,fuzzing",
         "--report", "junit", "--report-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=900, cwd=tmp_path)
    print(done.stdout[-6000:], done.stderr[-2000:])
    assert done.returncode == 0
