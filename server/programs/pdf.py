"""The progress report of a patient's programs as a PDF a therapist can file
(``GET /api/patients/{id}/progress.pdf``): per program one A4 page with what needs a look
(the flags), adherence per ISO week (done / prescribed), the range of each exercise over
its sessions against the target band, and pain and effort over time. Drawn with
matplotlib's object API (no pyplot state), as the session report."""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Sequence
from datetime import date, datetime, time, timedelta
from zoneinfo import ZoneInfo

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.dates import AutoDateLocator, DateFormatter, DayLocator
from matplotlib.figure import Figure

from ..db import models
from ..reports.pdf import A4, DISCLAIMER
from ..reports.words import ANGLE_WORDS, day_words
from .adherence import ProgramProgress

FLAG_WORDS = {"no_session": "No session", "range_falling": "Range falling",
              "pain_rising": "Pain rising"}


def _foot(fig: Figure, patient: models.Patient, clinic_name: str, therapist: str) -> None:
    """Whose report and whose patient, on each page above the disclaimer, as the session
    PDF says them: the clinic, the therapist, the patient with their clinic number and
    date of birth (two patients of one name told apart on paper)."""
    who = [patient.name]
    if patient.clinic_number:
        who.append(f"clinic no. {patient.clinic_number}")
    if patient.date_of_birth:
        who.append(f"born {day_words(patient.date_of_birth)}")
    line = " · ".join([*([clinic_name] if clinic_name else []), f"Therapist: {therapist}",
                       ", ".join(who)])
    fig.text(0.06, 0.036, line, fontsize=7.5, color="#333")


def _program_page(fig: Figure, patient: models.Patient, p: ProgramProgress, today: date,
                  zone: str, page: int, pages: int) -> None:
    fig.text(0.06, 0.965, "Exercise program progress", fontsize=15, weight="bold")
    fig.text(0.94, 0.965, f"{patient.name} · {patient.side} arm", ha="right", fontsize=9,
             color="#444")
    # wrapped within the page (a 120-character name; the zone ran past the edge on one
    # line: "(Europe/Zur"); 85 characters of 10 pt fit its 0.88 of A4's width
    heading = textwrap.wrap(
        f"{p.name} — version {p.version}, " + ("in force" if p.active else "not in force")
        + f" · {len(p.sessions)} session{'' if len(p.sessions) == 1 else 's'}", 85)
    heading.append(f"as of {day_words(today, weekday=True)}, the clinic's day ({zone})")
    for i, line in enumerate(heading):
        fig.text(0.06, 0.94 - 0.016 * i, line, fontsize=10)
    fig.text(0.06, 0.02, DISCLAIMER, fontsize=7, color="#666")
    fig.text(0.94, 0.02, f"page {page} of {pages}", ha="right", fontsize=7, color="#666")
    y = 0.931 - 0.016 * len(heading)
    if p.flags:
        fig.text(0.06, y, "Needs a look:", fontsize=10, weight="bold", color="#b03a2e")
        for f in p.flags:
            y -= 0.018
            fig.text(0.08, y, f"• {FLAG_WORDS.get(f.kind, f.kind)}: {f.message}", fontsize=9)
    elif not p.sessions:  # nothing to be regular or steady yet
        fig.text(0.06, y, "No flag: no session of this program yet.", fontsize=9)
    else:
        fig.text(0.06, y, "No flag: sessions regular, range and pain steady.", fontsize=9)
    y -= 0.03
    # adherence per week (the last 8)
    weeks = p.weeks[-8:]
    ax = fig.add_axes((0.06, y - 0.03 - 0.022 * (len(weeks) + 1), 0.88,
                       0.022 * (len(weeks) + 1)))
    ax.axis("off")
    rows = [[f"week of {day_words(w.monday)}", f"v{w.version}",
             f"{w.done.days} / {w.prescribed.days}",
             f"{w.done.sessions} / {w.prescribed.sessions}",
             f"{w.done.exercises} / {w.prescribed.exercises}",
             f"{w.done.repetitions} / {w.prescribed.repetitions}",
             "–" if w.adherence_percent is None else f"{w.adherence_percent:.0f} %"]
            for w in weeks]
    if rows:
        # days: the days with a session of the program against the days asked, the
        # patient page's Days and the phone's "This week" (adherence.week_days)
        table = ax.table(cellText=rows, colLabels=["week", "version", "days", "sessions",
                                                   "exercise-days", "repetitions",
                                                   "adherence"],
                         # the week's date is the longest cell ("week of 30 Nov 2026")
                         colWidths=[0.22, 0.08, 0.13, 0.13, 0.15, 0.15, 0.14],
                         loc="upper left", cellLoc="center")
        table.auto_set_font_size(False)
        table.set_fontsize(8)
    fig.text(0.06, y, "Adherence by week (done / prescribed)", fontsize=10, weight="bold")
    y = y - 0.06 - 0.022 * (len(weeks) + 1)
    # range per exercise against its target
    shown = [e for e in p.exercises if e.points]
    # one time axis for every chart: the program's first Monday to today (the clinic's)
    first = p.weeks[0].monday if p.weeks else today
    span = (datetime.combine(first, time(0), ZoneInfo(zone)),
            datetime.combine(today + timedelta(days=1), time(0), ZoneInfo(zone)))

    days = (span[1] - span[0]).days

    def dates(ax) -> None:
        ax.set_xlim(*span)
        # whole days, each named once (a short span's automatic ticks fell every 12 h)
        ax.xaxis.set_major_locator(
            DayLocator(interval=math.ceil(days / 7), tz=ZoneInfo(zone)) if days <= 60
            else AutoDateLocator(maxticks=8, tz=ZoneInfo(zone)))
        ax.xaxis.set_major_formatter(DateFormatter("%d %b", tz=ZoneInfo(zone)))
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    n = len(shown) + 1
    height = max(0.08, (y - 0.06) / n - 0.045)
    for i, e in enumerate(shown):
        top = y - i * (height + 0.045)
        ax = fig.add_axes((0.1, top - height, 0.84, height))
        xs = [pt.started_at for pt in e.points]
        ax.plot(xs, [pt.range_deg for pt in e.points], "o-", color="#4C72B0", label="range")
        low = [pt.target_max_deg - pt.target_min_deg for pt in e.points]
        # the target in force from each session on, drawn on to today's end
        ax.step([*xs, span[1]], [*low, low[-1]], where="post", color="#55A868",
                linestyle="--", label="target arc")
        ax.set_title(f"{e.title} — {ANGLE_WORDS.get(e.angle, e.angle)}: range per session [°]",
                     fontsize=9, loc="left")
        ax.set_ylim(0, 1.15 * max([*low, *(pt.range_deg or 0 for pt in e.points), 10]))
        dates(ax)
        ax.legend(fontsize=7, loc="lower left")
    top = y - len(shown) * (height + 0.045)
    ax = fig.add_axes((0.1, top - height, 0.84, height))
    pain = [pt for pt in p.pain if pt.pain is not None]
    effort = [pt for pt in p.pain if pt.effort is not None]
    if pain:
        ax.plot([pt.started_at for pt in pain], [pt.pain for pt in pain], "o-",
                color="#C44E52", label="pain (NRS)")
    if effort:
        ax.plot([pt.started_at for pt in effort], [pt.effort for pt in effort], "s--",
                color="#8172B3", label="effort (Borg CR10)")
    ax.set_ylim(0, 10.5)
    ax.set_title("Pain and effort given after the exercises (highest per session, 0–10)",
                 fontsize=9, loc="left")
    dates(ax)
    if pain or effort:
        ax.legend(fontsize=7, loc="upper left")
    else:
        ax.text(0.5, 0.5, "none given yet", ha="center", va="center", transform=ax.transAxes)


def progress_pdf(patient: models.Patient, programs: Sequence[ProgramProgress], today: date,
                 zone: str, clinic_name: str = "", therapist: str = "") -> bytes:
    """One page per program (a page saying there is none, without one); each page's foot
    names the clinic (``clinic_name``, if set), the ``therapist`` and the patient."""
    out = io.BytesIO()
    with PdfPages(out) as pdf:
        if not programs:
            fig = Figure(figsize=A4)
            fig.text(0.06, 0.965, "Exercise program progress", fontsize=15, weight="bold")
            fig.text(0.06, 0.93, f"{patient.name}: no program prescribed.", fontsize=10)
            _foot(fig, patient, clinic_name, therapist)
            pdf.savefig(fig)
        for i, p in enumerate(programs):
            fig = Figure(figsize=A4)
            _program_page(fig, patient, p, today, zone, i + 1, len(programs))
            _foot(fig, patient, clinic_name, therapist)
            pdf.savefig(fig)
    return out.getvalue()
