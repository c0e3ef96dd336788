"""A session's report as a typed structure (pydantic models, so the OpenAPI document
carries its schema) and how it is computed from the stored session.

Units: angles [deg], times [s] on the session's clock, angular velocities [deg/s],
percentages [%], smoothness and coefficients of variation dimensionless.

* **Samples.** The stored estimates (``stored_estimates``). The calibration poses are not
  exercise: from the first estimate to ``CALIBRATION_TAIL_S`` after the end of the last
  pose is left out (as ``armtrack estimate`` does); with no pose, nothing is left out.
* **``rom``** (``docs/spec/api.md``): per angle of ``REPORTED_ANGLES`` that moved
  (``estimator.metrics.rom``: robust extremes whose tails hold 0.1 s of samples each, moved
  when the range is ≥ 10°): min, max, range, AAOS normal range and percentage of it, the
  seed paper's Table 2 range and percentage, and the patient's target (``targets``).
* **``exercises``.** From ``exercise:<name>`` marks (each mark to its ``end:`` mark, or to
  the next exercise, or to the end); without marks, *detected*: the repetitions of every
  moved angle, grouped by their leading angle and in time (``detected_groups``).
  Per exercise and angle: repetitions (a full cycle out and back counted once,
  ``estimator.metrics.count_repetitions``: one excursion from rest and back, or on a
  both-ways angle a turn to each side, ``docs/programs.md``), and per excursion
  (``details``) movement time, peak angular velocity, SPARC and LDLJ, consistency (CV of
  amplitude and movement time per direction).
* **``quality``** (``quality.py``): sensors, sample rates, lost samples, magnetometer
  disturbances, the calibration used, warnings.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Literal

import numpy as np
from armtrack.estimator.arm.joints import REPORTED_ANGLES
from armtrack.estimator.errors import EstimatorError
from armtrack.estimator.metrics import (
    BOTH_WAYS,
    RangeOfMotion,
    Repetition,
    calibration_exclusion,
    consistency,
    count_repetitions,
    detect_repetitions,
    percent_of,
    range_of_motion_table,
    repetition_smoothness,
)
from armtrack.estimator.metrics.elbow_pivot import (
    split_elbow_repetitions,
    turn_terms,
    y_up_of_quats,
)
from armtrack.estimator.recording import Recording
from pydantic import BaseModel, Field
from sqlalchemy.orm import Session as DbSession

from ..builds import REPORTS
from ..db import models
from ..lru import BoundedLru
from ..store.coverage import session_coverage
from ..store.processing import stored_estimates
from ..store.recordings import session_recording
from .targets import Target

#: The angle names of ``docs/spec/kinematics.md`` and ``shoulder_elevation``.
AngleName = Literal[REPORTED_ANGLES]  # type: ignore[valid-type]

#: Movements with the same leading angle closer than this are one detected exercise [s].
GROUP_GAP_S = 8.0


class NoEstimates(Exception):
    """The session has no stored estimates (live, being processed, or refused)."""


def utc(moment: datetime | None) -> datetime | None:
    """SQLite gives naive datetimes back; they were stored in UTC."""
    if moment is None:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def finite(x: float | None, digits: int = 3) -> float | None:
    """A JSON-safe float: rounded, ``None`` for NaN / infinity / ``None``."""
    if x is None:
        return None
    x = float(x)
    return round(x, digits) if np.isfinite(x) else None


# --- the report's structure ---------------------------------------------------------

class RomEntry(BaseModel):
    """One angle's range of motion [deg] against normal values and the patient's target."""

    min: float = Field(description="robust minimum [deg]")
    max: float = Field(description="robust maximum [deg]")
    range: float = Field(description="max − min [deg]")
    normal_min: float | None = Field(description="AAOS normal minimum [deg]")
    normal_max: float | None = Field(description="AAOS normal maximum [deg]")
    percent_of_normal: float | None = Field(
        description="how far the session reached on the side it moved most, as a share of "
        "the normal range on that side of zero: max(max ÷ normal_max, min ÷ normal_min) × "
        "100, the second term only where normal_min < 0, clamped at 0 [%]")
    paper_min: float | None = Field(description="seed paper's Table 2 minimum [deg]")
    paper_max: float | None = Field(description="seed paper's Table 2 maximum [deg]")
    percent_of_paper: float | None = Field(
        description="the same side rule against the paper's Table 2 range [%]")
    target_min: float | None = Field(
        None, description="the target minimum in force when the session started [deg]: "
        "the program version's band when the session followed one (per exercise; for the "
        "session, where its exercises on the angle share one band), else the patient's")
    target_max: float | None = Field(
        None, description="the target maximum in force when the session started [deg] "
        "(as target_min)")
    percent_of_target: float | None = Field(
        None, description="the same side rule against the target: max(max ÷ target_max, "
        "min ÷ target_min) × 100, a term only for a side the target has, clamped at 0 [%]")
    target_reached: bool | None = Field(
        None, description="percent_of_target ≥ 100")
    samples: int = Field(description="estimates the range was taken from")


class RepetitionOut(BaseModel):
    """One excursion from rest and back (a repetition, or on a both-ways angle a turn to
    one side: half of one)."""

    start_s: float
    peak_s: float
    end_s: float
    direction: Literal[1, -1] = Field(
        description="+1 towards the angle's positive side (flexion, abduction, pronation…)")
    amplitude_deg: float
    movement_time_s: float
    peak_velocity_deg_s: float
    sparc: float | None = Field(description="spectral arc length of the whole repetition")
    ldlj: float | None = Field(description="log dimensionless jerk of the whole repetition")


class ConsistencyOut(BaseModel):
    """Coefficients of variation across the repetitions of one direction [-]."""

    direction: Literal[1, -1]
    repetitions: int
    amplitude_cv: float | None
    movement_time_cv: float | None


class AngleExercise(BaseModel):
    """The repetitions of one angle within one exercise."""

    angle: AngleName
    repetitions: int = Field(
        description="a full cycle out and back counted once: the excursions (details), or "
        "on a both-ways angle (forearm_pronation, wrist_flexion, wrist_deviation, "
        "shoulder_rotation) a turn to each side: the larger of the two directions' counts")
    mean_amplitude_deg: float | None
    mean_movement_time_s: float | None
    peak_velocity_deg_s: float | None = Field(description="largest of the repetitions")
    median_sparc: float | None
    median_ldlj: float | None
    consistency: list[ConsistencyOut]
    details: list[RepetitionOut]


class Exercise(BaseModel):
    """One exercise: a marked period, or repetitions detected close together in time."""

    name: str
    source: Literal["marks", "detected"]
    start_s: float
    end_s: float
    rom: dict[AngleName, RomEntry]
    angles: list[AngleExercise]


class Window(BaseModel):
    start_s: float
    end_s: float


class PoseOut(BaseModel):
    name: str
    start_s: float
    end_s: float


class SensorQuality(BaseModel):
    name: str
    nine_axis: bool
    samples: int
    rate_hz: float | None = Field(description="median sample rate [Hz]")
    duration_s: float
    lost_samples: int = Field(description="missing samples, from gaps in the time stamps")
    lost_percent: float
    gaps: list[Window] = Field(
        default_factory=list,
        description="time-stamp gaps over GAP_STEPS sample periods: data lost, a stalled "
                    "sensor, or a clock that jumped forward")
    magnetic_disturbances: list[Window] = Field(
        description="periods where the field strength left the sensor's usual value")
    magnetic_disturbance_s: float


class CalibrationQuality(BaseModel):
    method: str | None = Field(description="two-pose, n-pose or default")
    default_mounting: bool = Field(description="no pose found: the default mounting is used")
    carries_on: int | None = Field(
        None, description="the session this one carries on (carried-on/1), where the "
        "patient held the poses; null: none")
    words: str = Field("", description="which calibration was used, in a sentence for the "
                       "therapist (reports.words.calibration_words)")
    final_time_s: float | None
    poses: list[PoseOut]
    excluded: Window | None = Field(description="left out of every metric (the poses)")


class Quality(BaseModel):
    sensors: list[SensorQuality]
    estimates: int
    estimate_rate_hz: float | None
    estimate_gaps: list[Window] = Field(description="gaps of more than 0.25 s in estimates")
    calibration: CalibrationQuality
    estimator: dict[str, str]
    warnings: list[str]


class TargetOut(BaseModel):
    angle: AngleName
    min_deg: float
    max_deg: float
    note: str | None
    updated_at: datetime = Field(description="when this target was set")


class SessionInfo(BaseModel):
    session_id: int
    patient_id: int
    patient_name: str
    side: Literal["right", "left"]
    height_m: float | None
    status: str
    source: str
    started_at: datetime
    ended_at: datetime | None
    kit: str | None = Field(description="the device (sensor kit) that sent the session")
    sensors: list[str]
    measured_angles: list[str] = Field(
        default_factory=list, description="the angles the kit measures; the report shows "
        "only these (docs/extensions/measured-angles.md)")
    assumptions: dict[str, str] = Field(
        default_factory=dict, description="what the measured angles assume, by name")
    duration_s: float


class SessionReport(BaseModel):
    """A session's report (``docs/spec/api.md``)."""

    session: SessionInfo
    rom: dict[AngleName, RomEntry] = Field(
        description="the angles that moved, calibration poses excluded")
    exercises: list[Exercise]
    quality: Quality
    targets: list[TargetOut] = Field(
        description="the targets in force when the session started (what rom's target_* "
        "fields compare with; a followed program version's bands where it gives the "
        "angle one): a target set later does not rewrite the report")
    current_targets: list[TargetOut] = Field(
        default_factory=list, description="the patient's targets today, shown beside")


# --- computing it ------------------------------------------------------------------

@dataclass
class SessionData:
    """What a report is made of: the stored session, its estimates and its recording."""

    session: models.Session
    patient: models.Patient
    kit: str | None
    t: np.ndarray
    #: name → (N,) [deg]
    angles: dict[str, np.ndarray]
    #: segment → (N, 4) w, x, y, z (segment → world ENU)
    quats: dict[str, np.ndarray]
    recording: Recording
    exclude: list[tuple[float, float]] = field(default_factory=list)

    @functools.cached_property
    def angles_rad(self) -> dict[str, np.ndarray]:
        """``angles`` in [rad], made once."""
        return {k: np.deg2rad(v) for k, v in self.angles.items()}

    @functools.cached_property
    def forearm_turns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """A forearm-only kit's forearm sensor's turn terms ``(t, pull, across)`` (its
        times and ``turn_terms`` of its readings and its long axis's upward component,
        ``estimator/metrics/elbow_pivot.py``); None for any other kit."""
        sensors = self.recording.sensors
        if "forearm" not in sensors or "upper_arm" in sensors \
                or "forearm" not in self.quats or len(self.t) < 2:
            return None
        stream = sensors["forearm"]
        sensor_y = (self.session.calibration or {}).get("forearm_sensor_y")
        y_up = np.interp(stream.t, self.t, y_up_of_quats(self.quats["forearm"], sensor_y))
        return (stream.t, *turn_terms(stream.acc[:, 1], stream.gyr, y_up))

    def elbow_split(self, reps: Sequence[Repetition]
                    ) -> tuple[list[Repetition], list[tuple[Repetition, float]]]:
        """The elbow flexion's repetitions ``reps`` of a forearm-only kit split into the
        elbow's own and the straight arm's raises about the shoulder, with their radius
        [m] (``split_elbow_repetitions``, for the session's body); every one kept on any
        other kit."""
        turns = self.forearm_turns
        if turns is None:
            return list(reps), []
        return split_elbow_repetitions(reps, *turns, self.recording.segment_lengths())

    def credited(self, angle: str, reps: Sequence[Repetition]) -> Sequence[Repetition]:
        """``angle``'s repetitions that count: on a forearm-only kit an elbow flexion
        made about the shoulder (the arm raised straight) is not the elbow's."""
        return self.elbow_split(reps)[0] if angle == "elbow_flexion" else reps


def span(t: np.ndarray, start_s: float, end_s: float, closed: bool = False) -> slice:
    """The samples of ``t`` [s] (non-decreasing) in ``[start_s, end_s)`` (``closed``:
    ``[start_s - 1e-9, end_s + 1e-9]``, a repetition's as the smoothness takes it). A
    window's metrics read its samples only: masking the whole session once per exercise
    and per repetition made a report cost its length times its repetitions (1.89 M rows,
    2,392 repetitions: 70 s)."""
    if closed:
        return slice(int(np.searchsorted(t, start_s - 1e-9, "left")),
                     int(np.searchsorted(t, end_s + 1e-9, "right")))
    return slice(int(np.searchsorted(t, start_s, "left")),
                 int(np.searchsorted(t, end_s, "left")))


def no_estimates_words(session: models.Session) -> str:
    """Why ``session`` has no estimates, and what to do, by its state: live, interrupted
    (close it), empty, failed, or being estimated."""
    n = session.id
    if session.status == "live":
        return f"session {n} is live: its estimates come once it ends"
    if session.status == "interrupted":
        return (f"session {n} was interrupted (its kit may still resume it): close it to "
                f"estimate what was recorded ('Close and estimate' on its page, or POST "
                f"/api/sessions/{n}/close)")
    if not session.samples:
        return f"session {n} holds no samples: there is nothing to estimate"
    if session.processing_error:
        return f"session {n} could not be estimated: {session.processing_error}"
    return f"session {n} is being estimated: try again in a minute"


def load_session(db: DbSession, session: models.Session) -> SessionData:
    """The session's estimates and raw data; raises NoEstimates when none are stored."""
    columns, values = stored_estimates(db, session)
    if not columns:
        raise NoEstimates(no_estimates_words(session))
    patient = db.get(models.Patient, session.patient_id)
    device = db.get(models.Device, session.device_id) if session.device_id else None
    index = {c: i for i, c in enumerate(columns)}
    t = values[:, index["t"]]
    measured = set(session_coverage(session)["measured_angles"])  # the others stay 0
    angles = {k: values[:, index[k]] for k in REPORTED_ANGLES if k in index and k in measured}
    quats = {c[:-3]: values[:, index[c]:index[c] + 4] for c in columns if c.endswith("_qw")}
    recording = session_recording(db, session)
    poses = (session.calibration or {}).get("poses") or []
    exclude = calibration_exclusion(float(t[0]) if len(t) else 0.0, (p["end"] for p in poses))
    return SessionData(session=session, patient=patient, kit=device.name if device else None,
                       t=t, angles=angles, quats=quats, recording=recording, exclude=exclude)


def rom_entry(rom: RangeOfMotion, target: Target | None) -> RomEntry:
    entry = RomEntry(
        min=finite(rom.min_deg), max=finite(rom.max_deg), range=finite(rom.range_deg),
        normal_min=rom.normal_min_deg, normal_max=rom.normal_max_deg,
        percent_of_normal=finite(rom.percent_of_normal, 1),
        paper_min=rom.paper_min_deg, paper_max=rom.paper_max_deg,
        percent_of_paper=finite(rom.percent_of_paper, 1), samples=rom.samples)
    return apply_target(entry, target)


def apply_target(entry: RomEntry, target: Target | None) -> RomEntry:
    """``entry`` against ``target``, by the side rule of ``percent_of_normal``."""
    if target is None:
        return entry
    share = percent_of(entry.min, entry.max, (target.min_deg, target.max_deg))
    percent = finite(share, 1)
    return entry.model_copy(update={
        "target_min": target.min_deg, "target_max": target.max_deg,
        "percent_of_target": percent,
        "target_reached": None if percent is None else bool(share >= 100.0 - 1e-9)})


def rom_table(data: SessionData, include: Sequence[tuple[float, float]] | None,
              targets: Mapping[str, Target]) -> dict[str, RomEntry]:
    if not len(data.t):
        return {}
    rad, t = data.angles_rad, data.t
    if include is not None and len(include) == 1:  # one window: its samples only
        inside = span(t, *include[0])
        rad, t = {k: v[inside] for k, v in rad.items()}, t[inside]
    try:
        table = range_of_motion_table(rad, t, include=include,
                                      exclude=data.exclude or None)
    except EstimatorError:  # no sample left in the windows
        return {}
    return {name: rom_entry(rom, targets.get(name)) for name, rom in table.items()}


def exercise_windows(data: SessionData) -> list[tuple[str, float, float]]:
    """``(name, start_s, end_s)`` of the ``exercise:`` marks."""
    end_of_data = float(data.t[-1]) if len(data.t) else 0.0
    marks = sorted(data.recording.marks, key=lambda m: m.t)
    out = []
    for i, mark in enumerate(marks):
        if not mark.label.startswith("exercise:"):
            continue
        end = end_of_data
        for later in marks[i + 1:]:
            if later.label == f"end:{mark.label}" or later.label.startswith("exercise:"):
                end = later.t
                break
        if end > mark.t:
            out.append((mark.label.removeprefix("exercise:"), mark.t, end))
    return out


def repetitions_out(angle_rad: np.ndarray, t: np.ndarray,
                    reps: Sequence[Repetition]) -> list[RepetitionOut]:
    out = []
    for rep in reps:
        inside = span(t, rep.start_s, rep.end_s, closed=True)
        try:
            (smooth,) = repetition_smoothness(angle_rad[inside], t[inside], [rep])
            sparc, ldlj = smooth.sparc, smooth.ldlj
        except EstimatorError:
            sparc = ldlj = None
        out.append(RepetitionOut(
            start_s=finite(rep.start_s), peak_s=finite(rep.peak_s), end_s=finite(rep.end_s),
            direction=rep.direction, amplitude_deg=finite(rep.amplitude_deg, 2),
            movement_time_s=finite(rep.movement_time_s),
            peak_velocity_deg_s=finite(rep.peak_velocity_deg_s, 1),
            sparc=finite(sparc), ldlj=finite(ldlj)))
    return out


def angle_exercise(name: str, angle_rad: np.ndarray, t: np.ndarray,
                   reps: Sequence[Repetition]) -> AngleExercise:
    details = repetitions_out(angle_rad, t, reps)

    def mean(values: list[float | None]) -> float | None:
        values = [v for v in values if v is not None]
        return finite(float(np.mean(values))) if values else None

    def median(values: list[float | None]) -> float | None:
        values = [v for v in values if v is not None]
        return finite(float(np.median(values))) if values else None

    cons = []
    for direction in (1, -1):
        c = consistency(reps, direction)
        if c.repetitions:
            cons.append(ConsistencyOut(direction=direction, repetitions=c.repetitions,
                                       amplitude_cv=finite(c.amplitude_cv, 4),
                                       movement_time_cv=finite(c.movement_time_cv, 4)))
    return AngleExercise(
        angle=name, repetitions=count_repetitions(reps, name in BOTH_WAYS),
        mean_amplitude_deg=mean([d.amplitude_deg for d in details]),
        mean_movement_time_s=mean([d.movement_time_s for d in details]),
        peak_velocity_deg_s=max((d.peak_velocity_deg_s for d in details), default=None),
        median_sparc=median([d.sparc for d in details]),
        median_ldlj=median([d.ldlj for d in details]),
        consistency=cons, details=details)


def detected_name(angles: Sequence[str]) -> str:
    """The exercise's name from the angles that repeated: the shoulder's elevation is left
    out when a shoulder angle names the movement."""
    shown = [a for a in angles if a != "shoulder_elevation"
             or not {"shoulder_flexion", "shoulder_abduction"} & set(angles)]
    return " + ".join(shown)


def exercises(data: SessionData, moved: Sequence[str],
              targets: Mapping[str, Target]) -> list[Exercise]:
    if not len(data.t):
        return []
    rad = data.angles_rad
    exclude = data.exclude or None
    marked = exercise_windows(data)
    out: list[Exercise] = []
    if marked:
        for name, start, end in marked:
            rom = rom_table(data, [(start, end)], targets)
            angles = []
            inside = span(data.t, start, end)
            for angle in rom:
                reps = data.credited(angle, detect_repetitions(
                    rad[angle][inside], data.t[inside], include=[(start, end)],
                    exclude=exclude))
                if reps:
                    angles.append(angle_exercise(angle, rad[angle], data.t, reps))
            out.append(Exercise(name=name, source="marks", start_s=finite(start),
                                end_s=finite(end), rom=rom, angles=angles))
        return out
    # detected: every moved angle's repetitions, grouped in time
    found = {a: data.credited(a, detect_repetitions(rad[a], data.t, exclude=exclude))
             for a in moved}
    for a, b in detected_groups(found):
        angles = []
        for angle in moved:
            reps = [r for r in found[angle] if a <= r.start_s and r.end_s <= b]
            if reps:
                angles.append(angle_exercise(angle, rad[angle], data.t, reps))
        rom = rom_table(data, [(a, b + 1e-6)], targets)
        out.append(Exercise(name=detected_name([x.angle for x in angles]), source="detected",
                            start_s=finite(a), end_s=finite(b), rom=rom, angles=angles))
    return out


def detected_groups(found: Mapping[str, Sequence[Repetition]]) -> list[tuple[float, float]]:
    """Time spans ``(start_s, end_s)`` of detected exercises. Repetitions of any angles
    that overlap in time are one movement (a reach moves shoulder and elbow together); its
    *leading* angle is the one with the largest amplitude (the shoulder's elevation only
    when nothing else moved). Consecutive movements with the same leading angle, less than
    ``GROUP_GAP_S`` apart, are one exercise; a new leading angle or a longer pause starts
    the next."""
    reps = sorted(((r.start_s, r.end_s, r.amplitude, angle) for angle, rs in found.items()
                   for r in rs), key=lambda x: x[0])
    movements: list[list] = []  # [start, end, {angle: amplitude}]
    for a, b, amplitude, angle in reps:
        if movements and a < movements[-1][1]:
            m = movements[-1]
            m[1] = max(m[1], b)
            m[2][angle] = max(m[2].get(angle, 0.0), amplitude)
        else:
            movements.append([a, b, {angle: amplitude}])

    def leading(amplitudes: dict[str, float]) -> str:
        others = {k: v for k, v in amplitudes.items() if k != "shoulder_elevation"}
        chosen = others or amplitudes
        return max(chosen, key=chosen.get)

    groups: list[list] = []  # [start, end, leading angle]
    for a, b, amplitudes in movements:
        lead = leading(amplitudes)
        if groups and groups[-1][2] == lead and a - groups[-1][1] < GROUP_GAP_S:
            groups[-1][1] = max(groups[-1][1], b)
        else:
            groups.append([a, b, lead])
    return [(a, b) for a, b, _ in groups]


def target_out(target: Target) -> TargetOut:
    return TargetOut(angle=target.angle, min_deg=target.min_deg, max_deg=target.max_deg,
                     note=target.note, updated_at=utc(target.set_at))


def session_info(data: SessionData) -> SessionInfo:
    s = data.session
    return SessionInfo(
        session_id=s.id, patient_id=s.patient_id, patient_name=data.patient.name,
        side=s.side, height_m=s.height_m, status=s.status, source=s.source,
        started_at=utc(s.started_at), ended_at=utc(s.ended_at), kit=data.kit,
        sensors=list(s.sensors), **session_coverage(s),
        duration_s=finite(float(data.t[-1] - data.t[0]) if len(data.t) > 1 else 0.0, 2))


def build_report(data: SessionData, targets: Mapping[str, Target]
                 ) -> SessionReport:
    """The report of a loaded session, against the patient's ``targets`` (angle → row)."""
    from .quality import quality

    rom = rom_table(data, None, targets)
    return SessionReport(
        session=session_info(data), rom=rom, exercises=exercises(data, list(rom), targets),
        quality=quality(data), targets=[target_out(t) for t in targets.values()])


def rom_against(rom: Mapping[str, RomEntry], targets: Mapping[str, Target]
                ) -> dict[str, RomEntry]:
    """A range-of-motion table against ``targets`` (angle → target) instead of those it
    was made with."""
    cleared = {"target_min": None, "target_max": None, "percent_of_target": None,
               "target_reached": None}
    return {k: apply_target(v.model_copy(update=cleared), targets.get(k))
            for k, v in rom.items()}


def with_targets(report: SessionReport, targets: Mapping[str, Target],
                 current: Mapping[str, Target] | None = None,
                 bands: Mapping[str, tuple[str, Target | None]] | None = None
                 ) -> SessionReport:
    """The report against ``targets`` (angle → target: those in force at the session's
    time) instead of those it was made with; ``current``: today's, shown beside;
    ``bands``: the program version's exercises the session followed, name → (angle, its
    band or None), each exercise of that name judged on its angle against its band
    (``programs.stream.session_targets``)."""
    bands = bands or {}

    def of_exercise(name: str) -> Mapping[str, Target]:
        if name not in bands:
            return targets
        angle, band = bands[name]
        own = {k: v for k, v in targets.items() if k != angle}
        return own if band is None else {**own, angle: band}

    return report.model_copy(update={
        "rom": rom_against(report.rom, targets),
        "exercises": [e.model_copy(update={"rom": rom_against(e.rom, of_exercise(e.name))})
                      for e in report.exercises],
        "targets": [target_out(t) for t in targets.values()],
        "current_targets": [target_out(t) for t in (current or {}).values()]})


#: Reports of recent sessions without targets, by what identifies their estimates.
_CACHE: BoundedLru[tuple, SessionReport] = BoundedLru(64)


def report_key(session: models.Session) -> tuple:
    """What identifies a session's estimates (the cached report's key)."""
    return (session.id, session.started_at.isoformat(), session.samples, session.status,
            json.dumps(session.calibration, sort_keys=True, default=str),
            json.dumps(session.estimator, sort_keys=True, default=str),
            len(session.estimate_columns or ()))


def session_report(db: DbSession, session: models.Session,
                   targets: Mapping[str, Target] | None = None,
                   data: SessionData | None = None,
                   current: Mapping[str, Target] | None = None,
                   keep: bool = True) -> SessionReport:
    """The session's report (from ``data`` when loaded already) against ``targets``
    (default: those in force when the session started, the program version's bands if
    it followed one: ``programs.stream.session_targets``), with ``current``
    (default: today's) beside; raises NoEstimates. The computed report is kept for the
    next request while the session's estimates stay the same (``keep``; False for a
    one-off pass over many sessions, as an export: it would fill the cache with them)."""
    from ..programs.stream import session_targets, with_band_done
    from .targets import current_targets

    bands: Mapping[str, tuple[str, Target | None]] = {}
    if targets is None:
        targets, bands = session_targets(db, session)
    if current is None:
        current = current_targets(db, session.patient_id)
    key = report_key(session)
    base = _CACHE.get(key)
    if base is None:
        def build() -> SessionReport:
            # one build per session at a time: a request for it meanwhile takes this one
            if (found := _CACHE.get(key)) is not None:  # built while this one waited
                return found
            made = build_report(data or load_session(db, session), {})
            if keep:
                _CACHE.put(key, made)
            return made
        base = REPORTS.get(("report", key), build)
    if bands:  # an angle of two exercises with different bands: the one done's, if one
        targets = with_band_done(dict(targets), dict(bands), (e.name for e in base.exercises))
    return with_targets(base, targets, current, bands)
