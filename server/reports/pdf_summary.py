"""The PDF's first page: a one-page summary a doctor reads first — the clinic and the
therapist, the patient's identifiers, the local date and time, what was done, each
joint's range against normal, the target in force then and the previous sessions, the
change since last time, and a sentence of plain interpretation. Details follow on the
next pages; technical data sit in the appendix (``pdf.py``)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import date, datetime
from zoneinfo import ZoneInfo

from matplotlib.figure import Figure

from .content import RomEntry, SessionReport
from .words import ANGLE_WORDS, day_words, duration_words, exercise_words, set_words

LABELS = ANGLE_WORDS
#: A change of range smaller than this [deg] is "about the same" (within what one
#: session's estimate may differ from the next: the estimator's bar plus its extremes).
SAME_DEG = 3.0
#: "What was done": characters on a line (9 pt from the bullet to the frame's right
#: edge) and lines at most.
DONE_CHARS = 105
DONE_LINES = 8


#: Words after a session's date by what its start is (``Letterhead.dated``).
DATED_WORDS = {"recorded": " (recorded)", "uploaded": " (uploaded; recording time unknown)",
               "streamed": ""}


@dataclass(frozen=True)
class Letterhead:
    """Who files the report, about whom, and the clinic's time zone."""

    clinic_name: str = ""
    clinic_address: str = ""
    zone: ZoneInfo = field(default_factory=lambda: ZoneInfo("UTC"))
    #: the clinic's clock, ``24h`` or ``12h`` (``ARMTRACK_CLINIC_CLOCK``)
    clock: str = "24h"
    #: the program the session followed (its kit named it in hello), in words, if any
    program: str | None = None
    therapist: str = ""
    clinic_number: str | None = None
    date_of_birth: date | None = None
    #: what the session's start is: ``recorded``, ``uploaded`` (time unknown) or
    #: ``streamed`` (``SessionOut.dated``)
    dated: str = "streamed"
    #: the sets the kit began and never ended in the closed session (the patient left
    #: part way): ``(name, start_s, repetitions, asked)`` as the session page has them
    #: (``GET /api/sessions/{id}/summary``'s ``unfinished`` sets)
    unfinished: tuple[tuple[str, float, int | None, int | None], ...] = ()


def style_table(table, fontsize: float = 8, names_left: bool = True) -> None:
    """The reports' table look: light grey rules, a bold tinted header row, ``fontsize``
    [pt], and (``names_left``) the first column's names aligned left."""
    table.auto_set_font_size(False)
    table.set_fontsize(fontsize)
    for (row, col), cell in table.get_celld().items():
        cell.set_edgecolor("#bbb")
        if row == 0:
            cell.set_facecolor("#e8eef7")
            cell.set_text_props(weight="bold")
        elif col == 0 and names_left:
            cell.set_text_props(ha="left")


def local(moment: datetime, zone: ZoneInfo, with_time: bool = True,
          clock: str = "24h") -> str:
    """``Tue 1 Dec 2026, 09:41 CET`` in the clinic's zone, on its ``clock`` (``12h``:
    ``09:41 AM``, two-digit hours as the pages write them)."""
    at = moment.astimezone(zone)
    text = day_words(at.date(), weekday=True)
    time_of_day = f"{at:%I:%M %p}" if clock == "12h" else f"{at:%H:%M}"
    return text + (f", {time_of_day} {at.tzname()}" if with_time else "")


words = exercise_words


def _deg(x: float | None) -> str:
    return "–" if x is None else f"{round(x) + 0:d}°"


def _percent(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f} %"


def stopped_words(repetitions: int | None, asked: int | None) -> str:
    """"stopped after 4 of 10", as the session page says it (``stoppedWords``)."""
    if repetitions is None:
        return "stopped part way"
    return f"stopped after {repetitions}" + (f" of {asked}" if asked is not None else "")


def done_lines(report: SessionReport,
               unfinished: Sequence[tuple[str, float, int | None, int | None]] = ()
               ) -> list[str]:
    """What was done: each exercise with its repetitions and times; a set the patient left
    part way (``unfinished``) says so as the session page does, also one the report has
    no estimate in (begun as the recording ended)."""
    left = {(name, round(start, 3)): (reps, asked) for name, start, reps, asked in unfinished}
    rows: list[tuple[float, str, str]] = []  # (start, name, the line after "name: ")
    for e in report.exercises:
        reps = max((a.repetitions for a in e.angles), default=0)
        how = "marked by the kit" if e.source == "marks" else "recognised in the movement"
        when = f"{e.start_s:.0f}–{e.end_s:.0f} s into the session"
        stopped = left.pop((e.name, round(e.start_s, 3)), None) if e.source == "marks" else None
        if stopped is not None:
            rows.append((e.start_s, e.name, f"{stopped_words(*stopped)} ({when}, begun on "
                         "the kit and never ended: the patient stopped part way)"))
            continue
        # a marked set with no repetition (started and ended at once) is listed, as empty
        done = ("empty (no repetition)" if e.source == "marks" and not reps
                else f"{reps} repetition{'s' if reps != 1 else ''}")
        rows.append((e.start_s, e.name, f"{done} ({when}, {how})"))
    for (name, start), stopped in left.items():  # no estimate in it: not in the report
        rows.append((start, name, f"{stopped_words(*stopped)} (from {start:.0f} s into the "
                     "session, begun on the kit and never ended: the patient stopped part "
                     "way)"))
    rows.sort(key=lambda row: row[0])
    names = set_words([name for _, name, _ in rows])
    return [f"{name}: {text}" for name, (_, _, text) in zip(names, rows, strict=True)] or [
        "No repeated exercise was found (the range below is over the whole session, "
        "calibration poses left out)."]


def _previous_rom(previous: Sequence[tuple[datetime, SessionReport]], angle: str
                  ) -> tuple[datetime, RomEntry] | None:
    for started, report in previous:  # newest first
        if angle in report.rom:
            return started, report.rom[angle]
    return None


def interpretation(report: SessionReport,
                   previous: Sequence[tuple[datetime, SessionReport]],
                   zone: ZoneInfo) -> str:
    """A plain sentence or two about the joint that moved most (by share of normal)."""
    if not report.rom:
        return ("No joint moved more than 10° outside the calibration poses: nothing to "
                "compare in this session.")
    angle = max(report.rom, key=lambda k: (report.rom[k].percent_of_normal or 0.0,
                                           report.rom[k].range))
    r = report.rom[angle]
    negative_side = (r.normal_min is not None and r.normal_min < 0 and r.normal_max
                     and r.min / r.normal_min > r.max / r.normal_max)
    reach = r.min if negative_side else r.max
    text = f"{LABELS.get(angle, angle)} reached {_deg(reach)}"
    if r.percent_of_normal is not None:
        text += f" ({r.percent_of_normal:.0f} % of the normal range on that side)"
    before = _previous_rom(previous, angle)
    if before is not None:
        started, old = before
        change = r.range - old.range
        when = local(started, zone, with_time=False)
        if abs(change) < SAME_DEG:
            text += f", about the same range as on {when}"
        else:
            text += (f", {abs(change):.0f}° {'more' if change > 0 else 'less'} range than "
                     f"on {when}")
    else:
        text += "; this is the first estimated session to compare with"
    if r.target_max is not None:
        if r.target_reached:
            text += f". The target then ({_deg(r.target_min)} to {_deg(r.target_max)}) was reached."
        else:
            text += (f". The target then ({_deg(r.target_min)} to {_deg(r.target_max)}) was "
                     f"{_percent(r.percent_of_target)} reached.")
    else:
        text += "."
    return text


def summary_page(fig: Figure, report: SessionReport, letterhead: Letterhead,
                 previous: Sequence[tuple[datetime, SessionReport]]) -> None:
    """Draws the summary on ``fig`` (A4 portrait, the page frame drawn already)."""
    s = report.session
    lh = letterhead
    y = 0.93
    if lh.clinic_name:  # unset: no line (the server's log tells the operator at start)
        fig.text(0.06, y, lh.clinic_name, fontsize=11, weight="bold", color="#15324d")
    if lh.clinic_address:
        fig.text(0.06, y - 0.017 if lh.clinic_name else y,
                 lh.clinic_address.replace("\\n", ", "), fontsize=8, color="#444")
    fig.text(0.94, y, f"Therapist: {lh.therapist or '–'}", ha="right", fontsize=9)
    y -= 0.05
    started = s.started_at
    when = local(started, lh.zone, clock=lh.clock)
    dated = DATED_WORDS.get(lh.dated, "")
    rows = [
        ("Patient", s.patient_name),
        ("Clinic no.", lh.clinic_number or "–"),
        ("Date of birth", day_words(lh.date_of_birth) if lh.date_of_birth else "–"),
        # two lines: with "(uploaded; recording time unknown)" one ran past the frame
        ("Session", f"{when}{dated} · {duration_words(s.duration_s)}"),
        # the kit as the therapist named it ("Ada's phone", "kit H2"), not "kit kit H2"
        ("Arm and kit", f"{s.side} arm · " + (s.kit if s.kit else "uploaded file")),
    ]
    if lh.program:
        rows.append(("Program", lh.program))
    for key, value in rows:
        fig.text(0.06, y, key, fontsize=9, weight="bold")
        fig.text(0.22, y, value, fontsize=9)
        y -= 0.02
    y -= 0.015
    fig.text(0.06, y, "What was done", fontsize=11, weight="bold")
    y -= 0.022
    done = done_lines(report, lh.unfinished)
    lines: list[str] = []
    for k, line in enumerate(done):
        wrapped = textwrap.wrap("• " + line, DONE_CHARS, subsequent_indent="   ")
        if len(lines) + len(wrapped) > DONE_LINES - (k < len(done) - 1):
            more = len(done) - k
            lines.append(f"• {more} more exercise{'s' if more > 1 else ''} on page 4")
            break
        lines += wrapped
    for line in lines:
        fig.text(0.08, y, line, fontsize=9)
        y -= 0.019
    y -= 0.02
    fig.text(0.06, y, "Range of motion (degrees; calibration poses left out)", fontsize=11,
             weight="bold")
    y -= 0.01
    header = ["Joint", "This session", "% of normal", "Target then", "Previous session",
              "Change"]
    table_rows = []
    for angle, r in report.rom.items():
        before = _previous_rom(previous, angle)
        if before is not None:
            started_before, old = before
            prev = (f"{_deg(old.min)} to {_deg(old.max)} "
                    f"({local(started_before, lh.zone, with_time=False)})")
            change = f"{r.range - old.range:+.0f}°"
        else:
            prev, change = "–", "–"
        target = ("–" if r.target_max is None else
                  f"{_deg(r.target_min)} to {_deg(r.target_max)}: "
                  f"{_percent(r.percent_of_target)}" + (" ✓" if r.target_reached else ""))
        table_rows.append([LABELS.get(angle, angle), f"{_deg(r.min)} to {_deg(r.max)}",
                           _percent(r.percent_of_normal), target, prev, change])
    if table_rows:
        height = 0.026 * (len(table_rows) + 1)
        ax = fig.add_axes((0.06, y - height, 0.88, height))
        ax.axis("off")
        table = ax.table(cellText=table_rows, colLabels=header, cellLoc="center",
                         colWidths=[0.23, 0.13, 0.11, 0.19, 0.26, 0.08], bbox=(0, 0, 1, 1))
        style_table(table)
        y -= height + 0.02
    else:
        fig.text(0.08, y - 0.02, "No joint moved more than 10° outside the calibration.",
                 fontsize=9)
        y -= 0.05
    notes = [t for t in report.targets if t.note]
    if notes:
        fig.text(0.06, y, "Target notes: " + "; ".join(
            f"{LABELS.get(t.angle, t.angle)}: {t.note}" for t in notes)[:160], fontsize=8,
            color="#333")
        y -= 0.02
    changed = [t for t in report.current_targets
               if all((t.angle, t.min_deg, t.max_deg) != (u.angle, u.min_deg, u.max_deg)
                      for u in report.targets)]
    if changed:
        fig.text(0.06, y, "Targets set since this session (today's): " + "; ".join(
            f"{LABELS.get(t.angle, t.angle)} {_deg(t.min_deg)} to {_deg(t.max_deg)}"
            for t in changed)[:160], fontsize=8, color="#333")
        y -= 0.02
    y -= 0.015
    fig.text(0.06, y, "In plain words", fontsize=11, weight="bold")
    fig.text(0.07, y - 0.018, textwrap.fill(interpretation(report, previous, lh.zone), 88),
             fontsize=10, va="top", linespacing=1.5,
             bbox={"facecolor": "#f1f6fb", "edgecolor": "#c9d8e8",
                   "boxstyle": "round,pad=0.7"})
    fig.text(0.06, 0.045, textwrap.fill(
        "% of normal: how far the joint reached on the side it moved most, as a share of "
        "the AAOS normal range on that side of zero (flexion to 150° of −60…180° is 83 %). "
        "Target then: the target in force when the session was recorded. Details, curves "
        "and a technical appendix: pages 2 to 4.", 145), fontsize=7, color="#555")
