"""The report as a PDF a clinic files or sends, drawn with matplotlib (object API, no
pyplot state, so requests may draw at once in threads). A4 portrait, four pages:

1. the summary (``pdf_summary.py``): clinic, therapist, patient identifiers, local date
   and time, what was done, range against normal, the target then and the previous
   session, the change, a sentence of plain interpretation;
2. details: the range-of-motion table against AAOS normal values and the target in
   force when the session was recorded, and bars: normal range (grey), the session's
   range (blue), the target (black frame);
3. the joint angles that moved over time, the calibration part shaded, exercises as
   coloured bands with their names, each repetition's peak marked;
4. repetitions and smoothness per exercise and angle; appendix: data quality and
   technical data (sensors, rates, lost samples, magnetometer disturbances, calibration,
   estimator, warnings).
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from datetime import UTC, datetime

import matplotlib
import numpy as np
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.textpath import TextPath

from .content import Exercise, SessionData, SessionReport
from .pdf_summary import DATED_WORDS, Letterhead, local, style_table, summary_page
from .words import ANGLE_WORDS, calibration_words, duration_words, set_words

# Names and notes are a user's text: "$…$" in a patient's name is no formula (mathtext made
# such a name fail the whole PDF, issue 17). Set once for the process, not per call with
# rc_context (reports are drawn on several threads; rcParams are global). The reports
# use no mathtext.
matplotlib.rcParams["text.parse_math"] = False

A4 = (8.27, 11.69)
#: Rows of the repetitions table that fit on page 4 (a row: two lines of an exercise's
#: name).
MAX_EXERCISE_ROWS = 24
#: Characters on a line of an exercise's name in that table (6.5 pt in its column).
NAME_CHARS = 40
#: Points drawn per curve at most.
MAX_POINTS = 6000
DISCLAIMER = "armtrack supports therapy; it is not a diagnostic device."
#: Characters on a line of an angle's name where its cell or margin is narrow (page 2's
#: bars, page 4's table): "Shoulder internal rotation" on two lines.
ANGLE_CHARS = 18
POSES = {"npose": "N-pose", "tpose": "T-pose"}
SENSORS = {"trunk": "trunk", "clavicle": "clavicle", "upper_arm": "upper arm",
           "forearm": "forearm", "hand": "hand"}
COLOURS = ["#4C72B0", "#DD8452", "#55A868", "#C44E52", "#8172B3", "#937860", "#DA8BC3"]


def _angle(name: str, width: int | None = None) -> str:
    """An angle's name in words as the pages write it (``words.ANGLE_WORDS``), wrapped on
    lines of at most ``width`` characters when given."""
    text = ANGLE_WORDS.get(name, name)
    return "\n".join(textwrap.wrap(text, width)) if width else text


def _fmt(x: float | None, spec: str = ".0f", suffix: str = "") -> str:
    if x is None:
        return "–"
    text = f"{x:{spec}}"
    if text.startswith("-") and float(text) == 0:
        text = text[1:]  # no "-0"
    return text + suffix


def _page(title: str, report: SessionReport, page: int, pages: int) -> Figure:
    fig = Figure(figsize=A4)
    s = report.session
    fig.text(0.06, 0.965, title, fontsize=15, weight="bold")
    # below the title, not beside it: a long name beside a long title ran into it
    fig.text(0.94, 0.947, f"{s.patient_name} · session {s.session_id}", ha="right",
             fontsize=9, color="#444")
    fig.text(0.06, 0.02, DISCLAIMER, fontsize=7, color="#666")
    fig.text(0.94, 0.02, f"page {page} of {pages}", ha="right", fontsize=7, color="#666")
    return fig


#: Short words for the kit's assumptions (docs/extensions/measured-angles.md).
ASSUMPTION_WORDS = {"trunk_still": "trunk upright and still",
                    "upper_arm_still": "upper arm hanging still",
                    "forearm_still": "forearm still"}


def _header(fig: Figure, report: SessionReport, letterhead: Letterhead) -> None:
    s, q = report.session, report.quality
    started = s.started_at if s.started_at.tzinfo else s.started_at.replace(tzinfo=UTC)
    cal = q.calibration
    lines = [
        ("Patient", s.patient_name + (f", height {s.height_m:.2f} m" if s.height_m else "")),
        ("Date", local(started, letterhead.zone, clock=letterhead.clock)
                 + DATED_WORDS.get(letterhead.dated, "") + f", {duration_words(s.duration_s)}"),
        ("Side", f"{s.side} arm"),
        ("Kit", f"{s.kit or '(uploaded file)'} · sensors: "
                + ", ".join(SENSORS.get(n, n) for n in s.sensors)
                + (" · assumes: " + ", ".join(ASSUMPTION_WORDS.get(a, a) for a in s.assumptions)
                   if s.assumptions else "")),
        ("Calibration", calibration_words(cal.method, [(p.name, p.start_s, p.end_s)
                                                        for p in cal.poses],
                                          cal.carries_on, brief=True)),
    ]
    y = 0.925
    for key, value in lines:
        fig.text(0.06, y, key, fontsize=9, weight="bold")
        fig.text(0.22, y, value, fontsize=9)
        y -= 0.022


#: Height of a table row on the page [figure fraction].
ROW = 0.024
TABLE_TOP = 0.76


def _rom_table(fig: Figure, report: SessionReport, repetitions: dict[str, int]) -> float:
    """Draws the table below ``TABLE_TOP``; returns where it ends."""
    height = ROW * (len(report.rom) + 1) + 0.03
    ax = fig.add_axes((0.06, TABLE_TOP - height, 0.88, height))
    ax.axis("off")
    ax.set_title("Range of motion (degrees; calibration poses excluded)", loc="left",
                 fontsize=11, weight="bold")
    if not report.rom:
        ax.text(0, 0.5, "No joint moved more than 10° outside the calibration.", fontsize=9)
        return TABLE_TOP - height
    header = ["Angle", "Min", "Max", "Range", "Normal (AAOS)", "% normal", "Target",
              "% target", "Reps"]
    rows = []
    for angle, r in report.rom.items():
        target = (f"{r.target_min:.0f} … {r.target_max:.0f}" if r.target_min is not None
                  else "–")
        reached = "" if r.target_reached is None else (" ✓" if r.target_reached else " ✗")
        rows.append([_angle(angle), _fmt(r.min), _fmt(r.max), _fmt(r.range),
                     f"{r.normal_min:.0f} … {r.normal_max:.0f}" if r.normal_min is not None
                     else "–", _fmt(r.percent_of_normal, ".0f", "%"), target,
                     _fmt(r.percent_of_target, ".0f", "%") + reached,
                     str(repetitions.get(angle, 0))])
    table = ax.table(cellText=rows, colLabels=header, cellLoc="center",
                     colWidths=[0.25, 0.07, 0.07, 0.08, 0.13, 0.1, 0.12, 0.11, 0.07],
                     bbox=(0, 0, 1, 1 - 0.03 / height))
    style_table(table)
    return TABLE_TOP - height


def _rom_bars(fig: Figure, report: SessionReport, top: float) -> None:
    # the ticks and the axis' name below it stay above the page's footer
    height = min(top - 0.135, 0.09 * max(1, len(report.rom)) + 0.08)
    ax = fig.add_axes((0.25, top - 0.05 - height, 0.68, height))
    fig.text(0.06, top - 0.025, "Session range against normal and target", fontsize=11,
             weight="bold")
    names = list(report.rom)
    if not names:
        ax.axis("off")
        return
    y = np.arange(len(names))[::-1]
    ax.set_axisbelow(True)
    target_labelled = False
    for yi, angle in zip(y, names, strict=True):
        r = report.rom[angle]
        if r.normal_min is not None:
            ax.barh(yi, r.normal_max - r.normal_min, left=r.normal_min, height=0.7,
                    color="#dddddd", label="normal (AAOS)" if yi == y[0] else None)
        ax.barh(yi, r.range, left=r.min, height=0.4, color="#4C72B0",
                label="this session" if yi == y[0] else None)
        if r.target_min is not None:
            ax.barh(yi, r.target_max - r.target_min, left=r.target_min, height=0.6,
                    fill=False, edgecolor="black", linewidth=1.2, linestyle="--",
                    label=None if target_labelled else "target")
            target_labelled = True
        label = _fmt(r.percent_of_normal, ".0f", "% of normal")
        ax.text(max(r.max, r.normal_max or r.max) + 4, yi, label, va="center", fontsize=7)
    ax.set_yticks(y, [_angle(n, ANGLE_CHARS) for n in names], fontsize=8)
    # room right of the farthest bar for its "…% of normal" (about 50° wide at 7 pt)
    ax.set_xlim(-110, max([245.0] + [max(r.max, r.normal_max or r.max) + 4 + 60
                                     for r in report.rom.values()]))
    ax.axvline(0, color="#888", linewidth=0.6)
    ax.set_xlabel("angle [deg] (kinematics contract signs: flexion, abduction, internal "
                  "rotation, pronation, ulnar deviation +)", fontsize=7)
    ax.tick_params(axis="x", labelsize=8)
    ax.grid(axis="x", color="#eee")
    ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0, 1.0), ncol=3, frameon=False)


#: Width of page 3's charts [figure fraction] and of their band labels' font [pt].
CHART_WIDTH = 0.79
BAND_FONT = 7.0


def _band_label(ax, number: int, exercise: Exercise, name: str, t: np.ndarray) -> None:
    """Above an exercise's band: "3. Elbow flexion" where the band holds it, else "3."
    (page 4 numbers the exercises alike); nothing for a band outside the chart."""
    t0, t1 = (float(t[0]), float(t[-1])) if t.size > 1 else (0.0, 1.0)
    start, end = max(exercise.start_s, t0), min(exercise.end_s, t1)
    if end <= start:
        return
    band_pt = (end - start) / (t1 - t0) * CHART_WIDTH * A4[0] * 72
    text = f"{number}. {name}"
    # measured only where it may fit (a glyph is 0.2 em wide at least): measuring took
    # 12 ms a label, 6 s of a 500-exercise session's report (a kit's 1,000 marks), whose
    # bands are far too narrow for their names (att18)
    if band_pt < BAND_FONT * 0.2 * (len(text) - 1) \
            or TextPath((0, 0), text, size=BAND_FONT).get_extents().width > band_pt:
        text = f"{number}."
    ax.text(0.5 * (start + end), 1.02, text, transform=ax.get_xaxis_transform(),
            ha="center", fontsize=BAND_FONT, color=COLOURS[(number - 1) % len(COLOURS)],
            clip_on=False)


def _angles_page(fig: Figure, report: SessionReport, data: SessionData) -> None:
    names = list(report.rom) or ["elbow_flexion"]
    t = data.t
    stride = max(1, int(np.ceil(t.size / MAX_POINTS)))
    n = len(names)
    top, bottom = 0.92, 0.07
    height = (top - bottom) / n
    excluded = report.quality.calibration.excluded
    peaks: dict[str, list[tuple[float, float]]] = {}
    for exercise in report.exercises:
        for a in exercise.angles:
            for d in a.details:
                peaks.setdefault(a.angle, []).append((d.peak_s, d.direction))
    set_names = set_words([e.name for e in report.exercises])
    for i, angle in enumerate(names):
        # the angle's name and ticks left of the axes, inside the page's text frame
        ax = fig.add_axes((0.15, top - (i + 1) * height + 0.012, CHART_WIDTH,
                           height - 0.03))
        values = data.angles[angle]
        ax.plot(t[::stride], values[::stride], color="#1f3b66", linewidth=0.7)
        if excluded is not None:
            ax.axvspan(excluded.start_s, excluded.end_s, color="#cccccc", alpha=0.5,
                       linewidth=0)
        for k, (exercise, name) in enumerate(zip(report.exercises, set_names, strict=True)):
            ax.axvspan(exercise.start_s, exercise.end_s, color=COLOURS[k % len(COLOURS)],
                       alpha=0.12, linewidth=0)
            if i == 0:
                _band_label(ax, k + 1, exercise, name, t)
        if peaks.get(angle):
            pt = np.array([p for p, _ in peaks[angle]])
            ax.plot(pt, np.interp(pt, t, values), "v", color="#C44E52", markersize=3)
        rom = report.rom.get(angle)
        if rom is not None and rom.target_min is not None:
            for v in (rom.target_min, rom.target_max):
                ax.axhline(v, color="black", linestyle="--", linewidth=0.6)
        ax.set_ylabel(f"{_angle(angle)}\n[deg]", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(color="#eee")
        if i < n - 1:
            ax.tick_params(labelbottom=False)
        else:
            ax.set_xlabel("time [s] (grey: calibration, not counted; bands: exercises, "
                          "numbered as on page 4; ▼ repetition peaks)", fontsize=7)
        ax.set_xlim(float(t[0]) if t.size else 0, float(t[-1]) if t.size else 1)


#: Characters on a line of the appendix (7 pt across the page's 0.87 width).
APPENDIX_CHARS = 150


def _details_page(fig: Figure, report: SessionReport) -> None:
    fig.text(0.06, 0.92, "Repetitions and smoothness", fontsize=11, weight="bold")
    header = ["Exercise", "Angle", "Reps", "Amplitude", "Move time", "Peak vel.",
              "SPARC", "LDLJ", "CV ampl.", "CV time"]
    rows = []
    set_names = set_words([e.name for e in report.exercises])
    for k, (exercise, words) in enumerate(zip(report.exercises, set_names, strict=True), 1):
        name = "\n".join(textwrap.wrap(f"{k}. {words}", NAME_CHARS))
        for a in exercise.angles:
            main = max(a.consistency, key=lambda c: c.repetitions, default=None)
            rows.append([name, _angle(a.angle, ANGLE_CHARS), str(a.repetitions),
                         _fmt(a.mean_amplitude_deg, ".0f", "°"),
                         _fmt(a.mean_movement_time_s, ".2f", " s"),
                         _fmt(a.peak_velocity_deg_s, ".0f", "°/s"),
                         _fmt(a.median_sparc, ".2f"), _fmt(a.median_ldlj, ".1f"),
                         _fmt(main.amplitude_cv * 100 if main and main.amplitude_cv
                              is not None else None, ".0f", "%"),
                         _fmt(main.movement_time_cv * 100 if main and main.movement_time_cv
                              is not None else None, ".0f", "%")])
    note = ("Means over the repetitions; SPARC and LDLJ: medians (closer to 0 is smoother); "
            "CV: coefficient of variation of the direction with most repetitions.")
    # a row holds two lines of the name or angle; a longer one makes its row taller [rows]
    tall = [max(1.0, (max(row[0].count("\n"), row[1].count("\n")) + 1) / 2) for row in rows]
    shown = int(np.searchsorted(np.cumsum(tall), MAX_EXERCISE_ROWS, side="right"))
    if shown < len(rows):
        note = f"First {shown} of {len(rows)} rows (all in report.csv). " + note
        rows, tall = rows[:shown], tall[:shown]
    height = ROW * (max(1.0, sum(tall)) + 1)
    bottom = 0.9 - height
    ax = fig.add_axes((0.06, bottom, 0.88, height))
    ax.axis("off")
    if rows:
        table = ax.table(cellText=rows, colLabels=header, cellLoc="center",
                         colWidths=[0.27, 0.15, 0.05, 0.08, 0.08, 0.08, 0.06, 0.06, 0.07,
                                    0.07], bbox=(0, 0, 1, 1))
        for (row, _), cell in table.get_celld().items():  # the bbox keeps the ratios
            cell.set_height(tall[row - 1] if row else 1.0)
        style_table(table, fontsize=6.5, names_left=False)
    else:
        ax.text(0, 0.5, "No repetitions found.", fontsize=9)
    fig.text(0.06, bottom - 0.02, note, fontsize=7, color="#444")

    q = report.quality
    y = bottom - 0.07
    fig.text(0.06, y, "Appendix: data quality and technical data", fontsize=9,
             weight="bold")
    lines = []
    for sensor in q.sensors:
        lines.append(
            f"{SENSORS.get(sensor.name, sensor.name)} sensor: "
            f"{'9' if sensor.nine_axis else '6'}-axis, {sensor.samples} samples"
            f" at {_fmt(sensor.rate_hz, '.0f', ' Hz')} over {sensor.duration_s:.0f} s, "
            f"{sensor.lost_samples} lost ({sensor.lost_percent:.1f}%)"
            + (f", magnetic disturbance {sensor.magnetic_disturbance_s:.1f} s in "
               f"{len(sensor.magnetic_disturbances)} period(s)" if sensor.nine_axis else ""))
    cal = q.calibration
    lines.append(f"Estimates: {q.estimates} at {_fmt(q.estimate_rate_hz, '.0f', ' Hz')}, "
                 f"{len(q.estimate_gaps)} gap(s) > 0.25 s")
    lines.append(f"Calibration: {cal.words or cal.method or '–'}"
                 + (f"; excluded from metrics {cal.excluded.start_s:.1f}–"
                    f"{cal.excluded.end_s:.1f} s" if cal.excluded else ""))
    lines.append("Estimator: " + (", ".join(f"{k} {v}" for k, v in q.estimator.items())
                                  or "–") + f"; kit: {report.session.kit or 'uploaded file'}")
    lines += [f"Warning: {w}" for w in q.warnings] or ["No warnings."]
    y -= 0.025
    # wrapped here (matplotlib's wrap=True overlaps the next line), a line per 0.016
    wrapped = [part for line in lines
               for part in textwrap.wrap(line, APPENDIX_CHARS, subsequent_indent="  ")]
    for line in wrapped[: max(1, int((y - 0.05) / 0.016))]:
        fig.text(0.07, y, line, fontsize=7, color="#333")
        y -= 0.016


def report_pages(report: SessionReport, data: SessionData,
                 letterhead: Letterhead | None = None,
                 previous: Sequence[tuple[datetime, SessionReport]] = ()) -> list[Figure]:
    """The report's four pages as figures (A4 portrait, not yet drawn); ``previous``:
    earlier sessions' (start, report), newest first, for the summary's comparison."""
    letterhead = letterhead or Letterhead()
    repetitions: dict[str, int] = {}
    for exercise in report.exercises:
        for a in exercise.angles:
            repetitions[a.angle] = repetitions.get(a.angle, 0) + a.repetitions
    first = _page("Session report: summary", report, 1, 4)
    summary_page(first, report, letterhead, previous)
    second = _page("Range of motion in detail", report, 2, 4)
    _header(second, report, letterhead)
    _rom_bars(second, report, _rom_table(second, report, repetitions))
    third = _page("Joint angles over time", report, 3, 4)
    _angles_page(third, report, data)
    fourth = _page("Repetitions and smoothness; appendix", report, 4, 4)
    _details_page(fourth, report)
    return [first, second, third, fourth]


def report_pdf(report: SessionReport, data: SessionData,
               letterhead: Letterhead | None = None,
               previous: Sequence[tuple[datetime, SessionReport]] = ()) -> bytes:
    """The report as PDF bytes (``report_pages`` saved)."""
    out = io.BytesIO()
    with PdfPages(out, metadata={"Title": f"armtrack session {report.session.session_id}",
                                 "Creator": "armtrack"}) as pages:
        for fig in report_pages(report, data, letterhead, previous):
            pages.savefig(fig)
    return out.getvalue()
