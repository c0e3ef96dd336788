"""The session PDF's pages as drawn (server/reports/pdf.py ``report_pages``), with the
longest things a report prints: every table lies inside the page's text frame (the
title's left edge to the page number's right edge), every cell's words inside their cell,
no exercise name cut; and a server without ``ARMTRACK_CLINIC_NAME`` prints no operator's
hint on a document a patient may be given (pdftotext of the PDF)."""

from __future__ import annotations

import shutil
import subprocess
from datetime import UTC, datetime
from types import SimpleNamespace

import numpy as np
import pytest
from armtrack.server.reports.content import (
    AngleExercise,
    CalibrationQuality,
    ConsistencyOut,
    Exercise,
    PoseOut,
    Quality,
    RomEntry,
    SensorQuality,
    SessionInfo,
    SessionReport,
    TargetOut,
    Window,
)
from armtrack.server.reports.pdf import report_pdf
from armtrack.server.reports.pdf_summary import Letterhead

#: The widest figures each column prints (negative ranges, three-digit targets, ✓).
ANGLES = ["shoulder_rotation", "wrist_deviation", "clavicle_protraction",
          "shoulder_abduction", "forearm_pronation", "elbow_flexion"]
#: Exercise names as the kit's marks or detection give them: the longest combined one.
EXERCISES = ["shoulder_rotation + forearm_pronation + wrist_deviation",
             "clavicle_protraction + shoulder_abduction", "elbow_flexion"]


def rom(k: int) -> RomEntry:
    return RomEntry(min=-88.4 - k, max=178.6 - k, range=267.0, normal_min=-90.0,
                    normal_max=180.0, percent_of_normal=104.0, paper_min=None,
                    paper_max=None, percent_of_paper=None, target_min=-100.0,
                    target_max=170.0, percent_of_target=105.0, target_reached=True,
                    samples=4000)


def worst_report(session_id: int, started: datetime) -> SessionReport:
    angles = [AngleExercise(
        angle=a, repetitions=128, mean_amplitude_deg=-123.4, mean_movement_time_s=12.34,
        peak_velocity_deg_s=-1234.0, median_sparc=-12.34, median_ldlj=-123.4,
        consistency=[ConsistencyOut(direction=1, repetitions=64, amplitude_cv=1.234,
                                    movement_time_cv=1.234)], details=[])
        for a in ANGLES[:3]]
    exercises = [Exercise(name=n, source="marks", start_s=20.0 + 40 * k,
                          end_s=50.0 + 40 * k, rom={}, angles=angles)
                 for k, n in enumerate(EXERCISES)]
    sensor = SensorQuality(name="upper_arm", nine_axis=True, samples=123456, rate_hz=100.0,
                           duration_s=1234.0, lost_samples=1234, lost_percent=1.0,
                           magnetic_disturbances=[Window(start_s=1.0, end_s=2.0)],
                           magnetic_disturbance_s=1.0)
    return SessionReport(
        session=SessionInfo(
            session_id=session_id, patient_id=1,
            patient_name="Marie-Amélie de la Tour d'Auvergne-Lauraguais", side="right",
            height_m=1.75, status="closed", source="upload", started_at=started,
            ended_at=started, kit="kit-physio-room-2", sensors=["trunk", "upper_arm",
                                                                  "forearm", "hand"],
            duration_s=1234.5),
        rom={a: rom(k) for k, a in enumerate(ANGLES)}, exercises=exercises,
        quality=Quality(sensors=[sensor] * 4, estimates=123456, estimate_rate_hz=100.0,
                        estimate_gaps=[], calibration=CalibrationQuality(
                            method="two-pose", default_mounting=False, final_time_s=10.0,
                            poses=[PoseOut(name="npose", start_s=0.5, end_s=4.5)],
                            excluded=Window(start_s=0.0, end_s=10.0)),
                        estimator={"version": "0.1.0", "filter": "qcf"},
                        warnings=["the file's body height is 1.80 m; the patient's record "
                                  "says 1.75 m"]),
        targets=[TargetOut(angle=a, min_deg=-100.0, max_deg=170.0, note=None,
                           updated_at=started) for a in ANGLES],
        current_targets=[])


def worst_pages(letterhead: Letterhead | None = None):
    started = datetime(2026, 12, 30, 9, 41, tzinfo=UTC)
    report = worst_report(12345, started)
    previous = [(datetime(2026, 9, 30, 17, 5, tzinfo=UTC), worst_report(12000, started))]
    t = np.linspace(0.0, 150.0, 1501)
    data = SimpleNamespace(t=t, angles={a: 60 * np.sin(t) for a in ANGLES})
    letterhead = letterhead or Letterhead(
        clinic_name="Centre de rééducation fonctionnelle du Parc",
        clinic_address="12 Quai des Chartrons, 33000 Bordeaux", therapist="Dr Alice Martin",
        clinic_number="BX-2291-0042")
    return report, data, letterhead, previous


def frame(fig, renderer) -> tuple[float, float]:
    """The page's text frame [px]: the title's left edge, the page number's right edge."""
    texts = [t for t in fig.texts if t.get_text()]
    title = texts[0]
    number = next(t for t in texts if t.get_text().startswith("page "))
    return (title.get_window_extent(renderer).x0, number.get_window_extent(renderer).x1)


def test_an_unset_clinic_name_prints_no_setting_on_the_document():
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (Debian poppler-utils) is missing")
    report, data, _, previous = worst_pages()
    pdf = report_pdf(report, data, Letterhead(therapist="Dr Alice Martin"), previous)
    text = subprocess.run(["pdftotext", "-layout", "-", "-"], input=pdf,
                          capture_output=True, check=True).stdout.decode()
    print(text[:600])
    assert "ARMTRACK" not in text and "not set" not in text
    assert "Therapist: Dr Alice Martin" in text and "Session report: summary" in text
