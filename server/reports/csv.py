"""The report as CSV: one row per angle, for the whole session (``scope`` ``session``)
and for each exercise (``scope`` the exercise's name), and a patient's progress as one
row per session and angle. Angles [deg], times [s]; empty cells where a figure does not
apply. (The per-sample angles are ``/api/sessions/{id}/angles.csv``.)"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable

from ..spreadsheet import spreadsheet_text
from .content import AngleExercise, RomEntry, SessionReport

ROM_FIELDS = ("min", "max", "range", "normal_min", "normal_max", "percent_of_normal",
              "paper_min", "paper_max", "percent_of_paper", "target_min", "target_max",
              "percent_of_target", "target_reached")
REPETITION_FIELDS = ("repetitions", "mean_amplitude_deg", "mean_movement_time_s",
                     "peak_velocity_deg_s", "median_sparc", "median_ldlj")
SUMMARY_COLUMNS = ("session_id", "scope", "start_s", "end_s", "angle", *ROM_FIELDS,
                   *REPETITION_FIELDS, "amplitude_cv", "movement_time_cv")


def cell(value: object) -> object:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    return spreadsheet_text(value)


def _rows(report: SessionReport) -> Iterable[list[object]]:
    sid = report.session.session_id
    totals: dict[str, int] = {}
    for exercise in report.exercises:
        for a in exercise.angles:
            totals[a.angle] = totals.get(a.angle, 0) + a.repetitions
    for angle, rom in report.rom.items():
        yield [sid, "session", "", "", angle, *_rom(rom), totals.get(angle, 0),
               *[""] * (len(REPETITION_FIELDS) + 1)]
    for exercise in report.exercises:
        by_angle = {a.angle: a for a in exercise.angles}
        for angle in dict.fromkeys([*exercise.rom, *by_angle]):
            rom = exercise.rom.get(angle)
            reps = by_angle.get(angle)
            yield [sid, spreadsheet_text(exercise.name), exercise.start_s, exercise.end_s, angle,
                   *(_rom(rom) if rom else [""] * len(ROM_FIELDS)), *_reps(reps)]


def _rom(rom: RomEntry) -> list[object]:
    return [cell(getattr(rom, f)) for f in ROM_FIELDS]


def _reps(reps: AngleExercise | None) -> list[object]:
    if reps is None:
        return [0, *[""] * (len(REPETITION_FIELDS) + 1)]
    main = max(reps.consistency, key=lambda c: c.repetitions, default=None)
    return [*(cell(getattr(reps, f)) for f in REPETITION_FIELDS),
            cell(main.amplitude_cv if main else None),
            cell(main.movement_time_cv if main else None)]


def report_csv(report: SessionReport) -> str:
    """The summary table (``SUMMARY_COLUMNS``); coefficients of variation of the direction
    with the most repetitions."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(SUMMARY_COLUMNS)
    writer.writerows(_rows(report))
    return out.getvalue()
