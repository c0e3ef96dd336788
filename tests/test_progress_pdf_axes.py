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
