"""The session PDF's pages as drawn (server/reports/pdf.py ``report_pages``), with the
longest things a report prints: every table lies inside the page's text frame (the
title's left edge to the page number's right edge), every cell's words inside their cell,
no exercise name cut, nothing else past the frame or into other words, page 3's
exercise bands named; and a server without ``ARMTRACK_CLINIC_NAME`` prints no operator's
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
from armtrack.server.reports.pdf import report_pages, report_pdf
from armtrack.server.reports.pdf_summary import Letterhead
from armtrack.server.reports.words import exercise_words
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.table import Table

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


def test_every_table_fits_the_text_frame_and_every_cell_its_words():
    report, data, letterhead, previous = worst_pages()
    figures = report_pages(report, data, letterhead, previous)
    assert len(figures) == 4
    problems = []
    names_drawn = []
    for page, fig in enumerate(figures, 1):
        canvas = FigureCanvasAgg(fig)
        fig.set_dpi(100)
        canvas.draw()
        renderer = canvas.get_renderer()
        left, right = frame(fig, renderer)
        tables = [t for t in fig.findobj(Table)]
        for table in tables:
            box = table.get_window_extent(renderer)
            print(f"page {page}: table {box.x0:.1f}…{box.x1:.1f} px, "
                  f"text frame {left:.1f}…{right:.1f} px")
            if box.x0 < left - 0.5 or box.x1 > right + 0.5:
                problems.append(f"page {page}: table {box.x0:.0f}…{box.x1:.0f} px outside "
                                f"the text frame {left:.0f}…{right:.0f}")
            for (row, col), cell in table.get_celld().items():
                words = cell.get_text()
                if page == 4 and col == 0 and row > 0:
                    names_drawn.append(words.get_text())
                inside, cell_box = words.get_window_extent(renderer), cell.get_window_extent(
                    renderer)
                if (inside.x0 < cell_box.x0 - 0.5 or inside.x1 > cell_box.x1 + 0.5
                        or inside.y0 < cell_box.y0 - 0.5 or inside.y1 > cell_box.y1 + 0.5):
                    problems.append(f"page {page}: {words.get_text()!r} "
                                    f"({inside.width:.0f}×{inside.height:.0f} px) spills "
                                    f"out of its cell ({cell_box.width:.0f}×"
                                    f"{cell_box.height:.0f} px)")
        assert tables or page == 3, f"page {page} drew no table"
        # nothing else drawn past the frame either: headers, notes, appendix, charts
        # with their tick labels and axis names
        drawn = [(t.get_text()[:40], t.get_window_extent(renderer)) for t in fig.texts
                 if t.get_text()]
        drawn += [(ax.get_ylabel()[:40] or ax.get_title(loc="left")[:40] or "a chart",
                   ax.get_tightbbox(renderer)) for ax in fig.axes if ax.axison]
        for k, (what, box) in enumerate(drawn):
            problems += [f"page {page}: {what!r} runs into {other!r}"
                         for other, near in drawn[:k] if box.overlaps(near)]
            if box.x0 < left - 0.5 or box.x1 > right + 0.5:
                problems.append(f"page {page}: {what!r} {box.x0:.0f}…{box.x1:.0f} px")
    print("\n".join(problems))
    assert not problems
    # a long exercise name is wrapped, not cut: every name is there in full
    flat = [" ".join(n.split()) for n in names_drawn]
    for k, name in enumerate(EXERCISES, 1):
        assert f"{k}. {exercise_words(name)}" in flat, (name, flat)


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


def test_what_was_done_keeps_to_its_lines_and_says_what_is_left():
    """Many long exercises: the summary's list wraps inside the frame, stops at
    ``DONE_LINES`` and says how many more are on page 4 (none dropped silently)."""
    from armtrack.server.reports.pdf_summary import DONE_LINES

    report, data, letterhead, previous = worst_pages()
    many = [e.model_copy(update={"start_s": 20.0 + 40 * k, "end_s": 50.0 + 40 * k})
            for k, e in enumerate(report.exercises * 4)]
    figures = report_pages(report.model_copy(update={"exercises": many}), data, letterhead,
                           previous)
    bullets = [t.get_text() for t in figures[0].texts if t.get_text().startswith(("• ", "   "))]
    print("\n".join(bullets))
    assert len(bullets) <= DONE_LINES
    shown = sum(b.startswith("• ") for b in bullets[:-1])
    assert bullets[-1] == f"• {len(many) - shown} more exercises on page 4"


def test_page_3_names_each_exercise_band():
    """Each exercise's band on page 3 carries its number as on page 4 ("3."), with its
    name where the band is wide enough; the labels are drawn (they sat above the axes,
    clipped by them: never seen), inside the frame, apart."""
    report, data, letterhead, previous = worst_pages()
    fig = report_pages(report, data, letterhead, previous)[2]
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(100)
    canvas.draw()
    renderer = canvas.get_renderer()
    left, right = frame(fig, renderer)
    labels = []
    for ax in fig.axes:
        inside = ax.get_window_extent(renderer)
        for text in ax.texts:
            box = text.get_window_extent(renderer)
            seen = text.get_visible() and (not text.get_clip_on() or (
                inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0
                and box.y1 <= inside.y1))
            if seen:
                labels.append((text.get_text(), box))
    print([(t, round(b.x0), round(b.x1)) for t, b in labels])
    said = [t for t, _ in labels]
    for k, exercise in enumerate(report.exercises, 1):
        assert f"{k}. {exercise_words(exercise.name)}" in said or f"{k}." in said, (k, said)
    assert "3. Elbow flexion" in said  # its band holds the name
    for k, (what, box) in enumerate(labels):
        assert left - 0.5 <= box.x0 and box.x1 <= right + 0.5, what
        assert not any(box.overlaps(b) for _, b in labels[:k]), what


def test_page_2_share_labels_stay_inside_the_chart():
    """'104% of normal' beside a bar reaching 180° (shoulder flexion's normal end) ran
    into the chart's right edge."""
    report, data, letterhead, previous = worst_pages()
    fig = report_pages(report, data, letterhead, previous)[1]
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(100)
    canvas.draw()
    renderer = canvas.get_renderer()
    chart = next(ax for ax in fig.axes if ax.axison)
    edge = chart.get_window_extent(renderer).x1
    ends = [t.get_window_extent(renderer).x1 for t in chart.texts
            if t.get_text().endswith("of normal")]
    print(f"labels end at {max(ends):.1f} px, the chart at {edge:.1f} px")
    assert len(ends) == len(report.rom) and max(ends) < edge - 2


def test_angles_are_named_in_full_as_on_the_pages():
    """The angles on pages 2, 3 and 4 are named as the pages and page 1 name them
    (``words.ANGLE_WORDS``, "Shoulder internal rotation"), a long one wrapped in its cell,
    none shortened ("Shoulder int. rotation" was page 2's, 3's and 4's own word)."""
    from armtrack.server.reports.words import ANGLE_WORDS

    report, data, letterhead, previous = worst_pages()
    figures = report_pages(report, data, letterhead, previous)
    drawn = {2: [], 3: [], 4: []}
    for page in drawn:
        fig = figures[page - 1]
        for table in fig.findobj(Table):
            column = 1 if page == 4 else 0
            drawn[page] += [cell.get_text().get_text()
                            for (row, col), cell in table.get_celld().items()
                            if col == column and row > 0]
        drawn[page] += [t.get_text() for ax in fig.axes for t in ax.get_yticklabels()]
        drawn[page] += [ax.get_ylabel().rsplit("[deg]", 1)[0] for ax in fig.axes
                        if "[deg]" in ax.get_ylabel()]
    for page, names in drawn.items():
        flat = {" ".join(n.split()) for n in names if any(c.isalpha() for c in n)}
        print(f"page {page}: {sorted(flat)}")
        assert {ANGLE_WORDS[a] for a in ANGLES[:3]} <= flat, (page, flat)
        assert not any("." in n for n in flat), (page, flat)


def test_an_uploaded_sessions_date_says_so_within_the_frame():
    """An uploaded file without its recording time is dated by its upload: page 1 said
    "(uploaded; recording time unknown)" on a line that ran past the frame's right edge
    (with the kit's words after it), and page 2 gave the same date as the session's,
    unqualified. Now both say it, inside the frame."""
    import dataclasses

    report, data, letterhead, previous = worst_pages()
    letterhead = dataclasses.replace(letterhead, dated="uploaded")
    figures = report_pages(report, data, letterhead, previous)
    problems, dates = [], {}
    for page, fig in enumerate(figures[:2], 1):
        canvas = FigureCanvasAgg(fig)
        fig.set_dpi(100)
        canvas.draw()
        renderer = canvas.get_renderer()
        left, right = frame(fig, renderer)
        for t in fig.texts:
            box = t.get_window_extent(renderer)
            if t.get_text() and (box.x0 < left - 0.5 or box.x1 > right + 0.5):
                problems.append(f"page {page}: {t.get_text()!r} {box.x0:.0f}…{box.x1:.0f} px "
                                f"(frame {left:.0f}…{right:.0f})")
        dates[page] = " ".join(t.get_text() for t in fig.texts if "Dec 2026" in t.get_text())
    print(dates, problems, sep="\n")
    assert not problems
    for page in (1, 2):
        assert "uploaded; recording time unknown" in dates[page], (page, dates[page])


def test_what_was_done_lists_a_set_left_part_way_that_the_report_has_no_estimate_in():
    """A set the kit began as the recording ended has no estimate in it, so the report
    leaves it out; the session page still says "Pronation: stopped part way" (summary's
    ``unfinished``), and the PDF's "What was done" now says it too, in order, with the
    set numbers the page gives."""
    from armtrack.server.reports.pdf_summary import done_lines

    report, *_ = worst_pages()
    one = report.model_copy(update={"exercises": report.exercises[2:]})  # elbow, 100–130 s
    lines = done_lines(one, [("elbow_flexion", 140.0, None, 10), ("pronation", 60.0, 3, 10)])
    print("\n".join(lines))
    assert lines == [
        "Pronation: stopped after 3 of 10 (from 60 s into the session, begun on the kit "
        "and never ended: the patient stopped part way)",
        "Elbow flexion — set 1: 128 repetitions (100–130 s into the session, marked by the "
        "kit)",
        "Elbow flexion — set 2: stopped part way (from 140 s into the session, begun on the "
        "kit and never ended: the patient stopped part way)"]
