"""The progress PDF a therapist prints for a colleague named the patient by name alone
("Eva Hausmann · right arm"): no clinic, no therapist, no clinic number or date of birth,
which the session PDF prints. Two patients of one name could not be told apart on paper.
Now each page's foot says the clinic (``ARMTRACK_CLINIC_NAME``), the therapist and the
patient's clinic number and date of birth, as the session PDF does. A real server, the PDF
read back with pdftotext and drawn with pdftoppm (looked at: the foot clear of the
disclaimer and the charts)."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from server_support import ServerProcess

pytestmark = pytest.mark.skipif(shutil.which("pdftotext") is None,
                                reason="pdftotext (Debian poppler-utils) is missing")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("letterhead"),
                            {"ARMTRACK_CLINIC_NAME": "Physio Rhein"})
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


def pdf_text(content: bytes, path) -> str:
    path.write_bytes(content)
    subprocess.run(["pdftoppm", "-png", "-r", "70", str(path), str(path.with_suffix(""))],
                   check=True, timeout=120)
    return subprocess.run(["pdftotext", "-layout", str(path), "-"], capture_output=True,
                          text=True, check=True).stdout


@pytest.mark.parametrize("with_program", [True, False])
def test_the_progress_pdf_says_whose_and_from_which_clinic(server, tmp_path, with_program):
    api = server.client("alice")
    made = api.http.post("/api/patients", json={
        "name": "Eva Hausmann", "side": "right", "height_m": 1.64,
        "clinic_number": "4711", "date_of_birth": "1958-03-12"})
    assert made.status_code == 201, made.text
    patient = made.json()["id"]
    if with_program:
        program = api.http.post(f"/api/patients/{patient}/programs", json={
            "name": "Elbow after the fracture", "start_date": "2026-11-30", "exercises": [
                {"exercise": "elbow_flexion", "sets": 2, "repetitions": 5,
                 "days_per_week": 5}]})
        assert program.status_code == 201, program.text
    answer = api.http.get(f"/api/patients/{patient}/progress.pdf")
    assert answer.status_code == 200, answer.text[:300]
    text = pdf_text(answer.content, tmp_path / "progress.pdf")
    flat = " ".join(text.split())
    print("\n" + flat[-400:])
    assert "Physio Rhein" in flat
    assert "Therapist: alice" in flat
    assert "clinic no. 4711" in flat and "born 12 Mar 1958" in flat
