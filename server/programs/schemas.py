"""Request and response bodies of the programs' REST routes (``docs/programs.md``)."""

from __future__ import annotations

from datetime import date, datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .. import clock
from ..plain_text import Line, Note
from .catalogue import CATALOGUE

#: Target angles can be set within this [deg] (as the patients' targets).
LIMIT_DEG = 180.0
#: A program starts at most this many years before the day it is written: its adherence
#: lists every week from its start (a year typed 0001 for 2026 made 105,000 weeks).
START_YEARS_BACK = 10


class CatalogueOut(BaseModel):
    name: str
    title: str
    angle: str = Field(description="the angle repetitions and range are taken on")
    rest_deg: float = Field(description="default target band: where the movement starts")
    target_deg: float = Field(description="default target band: where it should reach")
    sensor: str = Field(description="the segment whose sensor measures it")
    repetitions: int = Field(description="the default count")
    both_ways: bool = Field(False, description=(
        "one repetition is a turn to each side of the rest (palm down, then up), not one "
        "excursion from rest and back (docs/programs.md, One repetition)"))
    instruction: str = Field(description="what the patient does, in a sentence")
    picture: str = Field(description="the name of the kit page's drawing")
    measurable: bool | None = Field(None, description=(
        "asked for a patient (patient_id): whether one of the patient's kits measures it "
        "(the sensors its sessions streamed with); null when none has streamed yet"))
    why_not: str | None = Field(None, description="when not measurable: why, in a sentence")


class ExerciseIn(BaseModel):
    """One exercise of a prescription, from the catalogue, with its dose."""

    model_config = ConfigDict(extra="forbid")
    exercise: str = Field(description="a catalogue name (GET /api/programs/catalogue)")
    sets: int = Field(ge=1, le=20)
    repetitions: int = Field(ge=1, le=100, description="per set")
    target_min_deg: float | None = Field(None, ge=-LIMIT_DEG, le=LIMIT_DEG,
                                         allow_inf_nan=False)
    target_max_deg: float | None = Field(None, ge=-LIMIT_DEG, le=LIMIT_DEG,
                                         allow_inf_nan=False)
    hold_s: float = Field(0.0, ge=0, le=60, allow_inf_nan=False,
                          description="hold at the end of the movement [s]")
    rest_s: float = Field(30.0, ge=0, le=600, allow_inf_nan=False,
                          description="rest between sets [s]")
    days_per_week: int = Field(ge=1, le=7)
    note: Note | None = Field(None, max_length=500)

    @model_validator(mode="after")
    def _check(self) -> ExerciseIn:
        if self.exercise not in CATALOGUE:
            raise ValueError(f"unknown exercise {self.exercise!r}; the catalogue has "
                             f"{', '.join(CATALOGUE)}")
        if (self.target_min_deg is None) != (self.target_max_deg is None):
            raise ValueError(f"{self.exercise}: give both target_min_deg and "
                             "target_max_deg, or neither (the patient's target applies)")
        if self.target_min_deg is not None and not self.target_min_deg < self.target_max_deg:
            raise ValueError(f"{self.exercise}: target_min_deg must be below target_max_deg, "
                             f"got {self.target_min_deg} and {self.target_max_deg}")
        return self


class PrescriptionIn(BaseModel):
    """What a version prescribes: dates (inclusive, the clinic's calendar), a note and
    the ordered exercises (each catalogue exercise at most once)."""

    model_config = ConfigDict(extra="forbid")
    start_date: date
    end_date: date | None = None
    note: Note | None = Field(None, max_length=2000)
    exercises: list[ExerciseIn] = Field(min_length=1, max_length=30)

    @model_validator(mode="after")
    def _check(self) -> PrescriptionIn:
        today = clock.now().date()  # the server's clock: a test's simulated calendar too
        earliest = today.replace(year=today.year - START_YEARS_BACK,  # 29 Feb: the 28th
                                 day=min(today.day, 28) if today.month == 2 else today.day)
        if self.start_date < earliest:
            raise ValueError(f"start_date {self.start_date} is more than {START_YEARS_BACK} "
                             f"years ago (the earliest is {earliest}): is the year right?")
        if self.end_date is not None and self.end_date < self.start_date:
            raise ValueError(f"end_date {self.end_date} is before start_date "
                             f"{self.start_date}")
        names = [e.exercise for e in self.exercises]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"an exercise is prescribed twice: {', '.join(twice)} (give "
                             "it more sets instead)")
        return self


class ProgramIn(PrescriptionIn):
    name: Line = Field(min_length=1, max_length=120,
                      description="unique among the patient's programs; a kit names it")


class ExerciseOut(BaseModel):
    exercise: str
    title: str
    angle: str = Field(description="the angle repetitions and range are taken on")
    sets: int
    repetitions: int
    target_min_deg: float | None = Field(description="as prescribed (null: not set here)")
    target_max_deg: float | None
    target: tuple[float, float] = Field(
        description="the target in force now [deg]: the version's, else the patient's "
                    "target for the angle, else the catalogue's")
    target_source: str = Field(description="program, patient or catalogue")
    hold_s: float
    rest_s: float
    days_per_week: int
    note: str | None


class VersionOut(BaseModel):
    id: int
    number: int
    created_at: datetime
    created_by: int | None
    start_date: date
    end_date: date | None
    note: str | None
    exercises: list[ExerciseOut]


class ProgramOut(BaseModel):
    id: int
    patient_id: int
    name: str
    created_at: datetime
    ended_at: datetime | None
    active: bool = Field(description="not ended, and today within the current version's "
                                     "dates")
    version: VersionOut = Field(description="the current (latest) version")
