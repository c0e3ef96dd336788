"""The progress PDF's charts, read off the drawn figure (server/programs/pdf.py): a date
axis names each day once (a program of a few days had 12-hour ticks labelled by day:
"30 Nov, 30 Nov, 01 Dec, 01 Dec, …"), and the target band's line shows from the first
session on (with one session its step line had one point and drew nothing)."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from types import SimpleNamespace

import pytest
from armtrack.server.programs.adherence import (
    Counts,
    ExercisePoint,
    ExerciseProgress,
    PainPoint,
    ProgramProgress,
    WeekAdherence,
)
from armtrack.server.programs.pdf import _program_page
from matplotlib.figure import Figure


def progress(first: date, today: date, sessions: list[datetime]) -> ProgramProgress:
    monday = first - timedelta(days=first.weekday())
    weeks = []
    while monday <= today:
        c = Counts(sessions=1, days=1, exercises=1, repetitions=6)
        weeks.append(WeekAdherence(week=f"{monday.isocalendar()[0]}-W{monday.isocalendar()[1]:02d}",
                                   monday=monday, version=1, active_days=7, prescribed=c,
                                   done=c, adherence_percent=100.0))
        monday += timedelta(days=7)
    points = [ExercisePoint(session_id=i, day=t.date(), started_at=t, version=1,
                            repetitions=6, range_deg=100.0 + i, min_deg=0.0,
                            max_deg=100.0 + i, target_min_deg=0.0, target_max_deg=120.0,
                            target_source="catalogue", target_reached=False)
              for i, t in enumerate(sessions)]
    return ProgramProgress(
        program_id=1, name="Elbow", active=True, version=1, sessions=[], weeks=weeks,
        exercises=[ExerciseProgress(exercise="elbow_flexion", title="Bend the elbow",
                                    angle="elbow_flexion", points=points)],
        pain=[PainPoint(session_id=0, day=sessions[0].date(), started_at=sessions[0], pain=2,
                        effort=4.0)],
        flags=[])


@pytest.mark.parametrize("days", [0, 3, 10, 40, 200])
def test_dates_named_once_and_the_target_drawn(days):
    today = date(2026, 12, 2)
    first = today - timedelta(days=days)
    sessions = [datetime.combine(first, datetime.min.time(), UTC) + timedelta(hours=10)]
    if days:
        sessions.append(datetime.combine(today, datetime.min.time(), UTC)
                        + timedelta(hours=9))
    fig = Figure(figsize=(8.27, 11.69))
    patient = SimpleNamespace(name="Ada", side="left")
    _program_page(fig, patient, progress(first, today, sessions), today, "UTC", 1, 1)
    fig.canvas.draw()
    charts = [ax for ax in fig.axes if ax.get_title(loc="left")]
    assert len(charts) == 2
    for ax in charts:
        labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
        print(days, ax.get_title(loc="left")[:20], labels)
        assert len(labels) >= 2, labels
        assert len(labels) == len(set(labels)), f"a day named twice: {labels}"
        assert len(labels) <= 8, labels
    target = [ln for ln in charts[0].get_lines() if ln.get_label() == "target arc"]
    assert target and len(target[0].get_xdata()) >= 2, "the target line has no length"


def _texts(fig) -> list[str]:
    """Every text drawn on the page: the figure's lines and the tables' cells."""
    from matplotlib.table import Table

    texts = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        texts += [t.get_text() for t in ax.texts]
        for child in ax.get_children():
            if isinstance(child, Table):
                texts += [cell.get_text().get_text() for cell in child.get_celld().values()]
    return texts


def test_weeks_and_days_are_named_as_dates_and_no_flag_claims_no_sessions():
    """Found on a patient's progress PDF beside the pages: the adherence rows read
    "2026-W49" and the header "as of 2026-12-03" where the page says "week of Nov 30, 2026"
    (d296af1) and the session PDF "Thu 3 Dec 2026"; a program with no session yet said
    "No flag: sessions regular, range and pain steady"."""
    today = date(2026, 12, 3)
    fig = Figure(figsize=(8.27, 11.69))
    patient = SimpleNamespace(name="Ada", side="left")
    p = progress(date(2026, 11, 25), today, [datetime(2026, 11, 25, 10, tzinfo=UTC)])
    _program_page(fig, patient, p, today, "UTC", 1, 1)
    texts = _texts(fig)
    print("\n".join(texts))
    assert "week of 23 Nov 2026" in texts and "week of 30 Nov 2026" in texts
    assert not [t for t in texts if "-W4" in t], "an ISO week code is left"
    assert any("as of Thu 3 Dec 2026, the clinic's day (UTC)" in t for t in texts)

    empty = Figure(figsize=(8.27, 11.69))
    _program_page(empty, patient, p.model_copy(update={"sessions": []}), today, "UTC", 1, 1)
    flag_lines = [t for t in _texts(empty) if t.startswith("No flag")]
    print(flag_lines)
    assert flag_lines and "regular" not in flag_lines[0]
