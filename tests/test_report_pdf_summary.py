"""The PDF a doctor reads, on a real server: the first page is a summary with the clinic,
the therapist, the patient's identifiers, the local date and time, what was done, the
range against normal, the target in force then, the previous session and the change, and
a plain sentence. Pages are rendered with pdftoppm (kept in ``ARMTRACK_SHOTS`` or a temp
folder, to be looked at) and read back with pdftotext."""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest
from armtrack.estimator.recording import format_recording, read_recording
from server_support import ServerProcess


@pytest.fixture(scope="module")
def clinic(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("pdf"), {
        "ARMTRACK_CLINIC_NAME": "Rehab Clinic Nord",
        "ARMTRACK_CLINIC_ADDRESS": "12 Quai des Chartrons, 33000 Bordeaux",
        "ARMTRACK_CLINIC_TIMEZONE": "Europe/Paris"})
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


def test_the_first_page_is_a_summary_a_doctor_reads(clinic, recordings_dir, tmp_path):
    if shutil.which("pdftoppm") is None or shutil.which("pdftotext") is None:
        pytest.skip("pdftoppm/pdftotext (Debian poppler-utils) are missing")
    alice = clinic.client("alice")
    alice.http.patch("/api/me", json={"full_name": "Dr Alice Martin"})
    patient = alice.http.post("/api/patients", json={
        "name": "Marie Curie", "side": "right", "height_m": 1.75,
        "clinic_number": "BX-2291", "date_of_birth": "1967-11-07"}).json()

    def upload(name, start_time):
        recording = read_recording(recordings_dir / f"{name}.csv")
        recording = replace(recording, metadata={**recording.metadata,
                                                 "start_time": start_time})
        answer = alice.http.post("/api/recordings", data={"patient_id": patient["id"]},
                                 files={"file": (f"{name}.csv", format_recording(recording))})
        assert answer.status_code == 201, answer.text
        return answer.json()

    alice.http.put(f"/api/patients/{patient['id']}/targets/elbow_flexion",
                   json={"min_deg": 0, "max_deg": 130, "note": "week 2: full flexion"})
    upload("elbow_6axis", "2026-11-24T09:30:00+01:00")  # before the target: recorded then
    latest = upload("elbow_flexion", "2026-12-01T09:41:00+01:00")
    # the target was set now, after both recordings: neither report shows it as "then"
    answer = alice.http.get(f"/api/sessions/{latest['id']}/report.pdf")
    assert answer.status_code == 200, answer.text[:300]
    folder = Path(os.environ.get("ARMTRACK_SHOTS", tmp_path))
    folder.mkdir(parents=True, exist_ok=True)
    pdf = folder / "report.pdf"
    pdf.write_bytes(answer.content)
    subprocess.run(["pdftoppm", "-png", "-r", "80", str(pdf), str(folder / "pdf-page")],
                   check=True, timeout=120)
    pages = sorted(folder.glob("pdf-page-*.png"))
    assert len(pages) == 4, pages
    first = subprocess.run(["pdftotext", "-f", "1", "-l", "1", "-layout", str(pdf), "-"],
                           capture_output=True, text=True, check=True).stdout
    print(first)
    flat = " ".join(first.split())  # wrapped lines joined
    for words in ("Rehab Clinic Nord", "12 Quai des Chartrons", "Dr Alice Martin",
                  "Marie Curie", "BX-2291", "7 Nov 1967", "Tue 1 Dec 2026, 09:41 CET",
                  "(recorded)", "Elbow flexion: 5 repetitions", "% of normal",
                  "Previous session", "Tue 24 Nov 2026", "In plain words",
                  "10° more range than on Tue 24 Nov 2026", "Targets set since this session"):
        assert words in flat, words
    assert "UTC" not in first and "upper_arm" not in first and "estimator" not in first
    assert "ARMTRACK_CLINIC_NAME" not in clinic.log.read_text()  # set: nothing to say
    # the duration in the words the session page uses ("35 s", "2 min 05 s"), not "0.6 min"
    seconds = round(alice.http.get(f"/api/sessions/{latest['id']}/summary").json()["duration_s"])
    duration = f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"
    print(f"duration: {duration}")
    assert f"(recorded) · {duration} Arm and kit right arm" in flat, duration
    appendix = subprocess.run(["pdftotext", "-f", "4", "-l", "4", str(pdf), "-"],
                              capture_output=True, text=True, check=True).stdout
    assert "Appendix" in appendix and "Estimator" in appendix


def test_a_duration_reads_as_the_pages_read_it():
    """``words.duration_words`` says a duration as ``fmtDuration`` (web/pages/static/app.js)
    does, halves included: ``Math.round`` rounds a half up, Python's ``round`` to even (a
    40.5-s session read '41 s' on its page and '40 s' in its PDF)."""
    from armtrack.server.reports.words import duration_words

    pages = {0.4: "0 s", 35.2: "35 s", 40.5: "41 s", 59.5: "1 min 00 s",
             62.5: "1 min 03 s", 125.0: "2 min 05 s", 3599.4: "59 min 59 s",
             3599.5: "1 h 00 min", 3917.0: "1 h 05 min", 72055.5: "20 h 00 min"}
    said = {seconds: duration_words(seconds) for seconds in pages}
    print(said)
    assert said == pages


def test_the_summary_names_the_kit_as_the_therapist_did(clinic):
    """Found by a new user: a session streamed by the kit the therapist named "kit H2" read
    "Arm and kit: right arm · kit kit H2" (and "kit Ada's phone" for a phone): the word
    "kit" was put before whatever name it had. The row says the arm, then the kit's name."""
    import sys

    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (Debian poppler-utils) is missing")
    alice = clinic.client("alice")
    patient = alice.patient("Named Kit")
    token = alice.device(patient["id"], "kit H2")["token"]
    subprocess.run(
        [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise", "elbow_flexion",
         "--url", clinic.ws_url, "--token", token, "--quiet", "--speed", "0"],
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120)
    session = alice.http.get(f"/api/patients/{patient['id']}/sessions").json()[0]
    alice.wait_processed(session["id"], timeout=120)
    answer = alice.http.get(f"/api/sessions/{session['id']}/report.pdf")
    assert answer.status_code == 200, answer.text[:300]
    first = subprocess.run(["pdftotext", "-f", "1", "-l", "1", "-", "-"], input=answer.content,
                           capture_output=True, check=True).stdout.decode()
    line = next(x for x in first.splitlines() if "right arm" in x)
    print(f"\nthe summary's arm and kit: {line!r}")
    assert "right arm · kit H2" in line and "kit kit" not in first
