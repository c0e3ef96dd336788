"""The stored data: therapists, patients, devices, sessions, raw samples, marks and
estimates (SQLAlchemy 2.0 typed models; the schema itself is made by the migrations).

Samples and estimates are stored in blocks: one row holds one ingest message's rows (or a
slice of an uploaded file) as packed float64, so a 30-minute session is a few thousand
rows, not half a million ORM objects. Times are seconds on the kit's clock.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Date,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    TypeDecorator,
    UniqueConstraint,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

from ..text_direction import shown


def utcnow() -> datetime:
    return datetime.now(UTC)


class UtcDateTime(TypeDecorator):
    """A moment stored in UTC and always read back with its time zone: SQLite keeps no
    zone and gave naive datetimes back, which the API then sent without one
    (``DateTime(timezone=True)`` in the schema, unchanged)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_result_value(self, value: datetime | None, dialect) -> datetime | None:
        if value is None or value.tzinfo is not None:
            return value
        return value.replace(tzinfo=UTC)


class Name(TypeDecorator):
    """A name (of a patient, a therapist, a kit, a program), read back with any direction
    control written out (``text_direction.shown``: "Anna[U+202E]evil"): refused at input since
    they make a name show reordered, but a database from before may hold one, and every
    page, report and export reads names through here (stored as it is, unchanged)."""

    impl = String
    cache_ok = True

    def process_result_value(self, value: str | None, dialect) -> str | None:
        return shown(value)


def never_reused() -> dict[str, Any]:
    """Table options: an id is never given twice, even after its row is deleted (SQLite's
    AUTOINCREMENT; PostgreSQL's sequences never repeat). Migration 0006 converted the
    tables made before it; every new table with an integer id takes this too."""
    return {"sqlite_autoincrement": True}


class Base(DeclarativeBase):
    type_annotation_map: ClassVar = {dict[str, Any]: JSON, list[Any]: JSON,
                                     datetime: UtcDateTime}


class Therapist(Base):
    __tablename__ = "therapists"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(128), unique=True)
    password_hash: Mapped[str] = mapped_column(String(256))
    created_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)
    #: a clinic admin manages therapists (and reassigns patients); not their patients' data
    is_admin: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    #: a disabled therapist cannot sign in, and their tokens stop working at once
    disabled_at: Mapped[datetime | None] = mapped_column(UtcDateTime)
    #: the name reports and pages show ("Dr Jane Doe"); the user name when unset
    full_name: Mapped[str | None] = mapped_column(Name(200))


class AccessToken(Base):
    """A therapist's sign-in: the SHA-256 of an opaque bearer token, until ``expires_at``."""

    __tablename__ = "access_tokens"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    therapist_id: Mapped[int] = mapped_column(
        ForeignKey("therapists.id", ondelete="CASCADE"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    expires_at: Mapped[datetime] = mapped_column(UtcDateTime)


class Patient(Base):
    __tablename__ = "patients"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    therapist_id: Mapped[int] = mapped_column(
        ForeignKey("therapists.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(Name(200))
    side: Mapped[str] = mapped_column(String(5))
    height_m: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)
    #: the clinic's own patient number (its records' identifier), optional
    clinic_number: Mapped[str | None] = mapped_column(Name(64))
    date_of_birth: Mapped[date | None] = mapped_column(Date)
    #: when the therapist discharged the patient (docs/extensions/discharge.md): their
    #: records stay, their kits start no new session; None while in care
    discharged_at: Mapped[datetime | None] = mapped_column(UtcDateTime)

    @classmethod
    def discharged_is(cls, discharged: bool):
        """The SQL condition of the patients discharged (``True``) or in care (``False``):
        the lists' ``discharged=`` query parameter."""
        return cls.discharged_at.is_not(None) if discharged else cls.discharged_at.is_(None)


class Device(Base):
    """A sensor kit of one patient; its token is stored as a SHA-256 only."""

    __tablename__ = "devices"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(
        ForeignKey("patients.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(Name(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(UtcDateTime)


class Session(Base):
    """One recording session: streamed live (``source`` ``stream``) or uploaded.

    ``status``: ``live``, ``interrupted`` (the stream went away and may resume), ``closed``.
    ``sensors``: {name: {"nine_axis": bool}}. ``calibration``: the poses and method the
    estimates used. ``estimator``: version and settings of the stored estimates.
    """

    __tablename__ = "sessions"
    __table_args__ = (Index("ix_sessions_device_created", "device_id", "created_at"),
                      never_reused())

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(
        ForeignKey("patients.id", ondelete="CASCADE"), index=True)
    device_id: Mapped[int | None] = mapped_column(
        ForeignKey("devices.id", ondelete="SET NULL"))
    source: Mapped[str] = mapped_column(String(10))
    status: Mapped[str] = mapped_column(String(12), index=True)
    side: Mapped[str] = mapped_column(String(5))
    height_m: Mapped[float | None] = mapped_column(Float)
    lengths: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    rate_hz: Mapped[float | None] = mapped_column(Float)
    sensors: Mapped[dict[str, Any]] = mapped_column(JSON)
    meta: Mapped[dict[str, Any]] = mapped_column("metadata", JSON, default=dict)
    started_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)
    ended_at: Mapped[datetime | None] = mapped_column(UtcDateTime)
    #: when the server stored it (an upload's arrival, whatever the file says; a kit's
    #: new sessions an hour are counted by it)
    created_at: Mapped[datetime | None] = mapped_column(UtcDateTime, default=utcnow)
    samples: Mapped[int] = mapped_column(BigInteger, default=0)
    calibration: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    estimator: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    estimate_columns: Mapped[list[Any] | None] = mapped_column(JSON)
    processing_error: Mapped[str | None] = mapped_column(String(2000))
    #: the kit's remembered gyroscope biases the session's filters start from, as they
    #: were when it began (docs/gyro-bias-memory.md's JSON); None: none remembered
    gyro_bias_prior: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    #: how far the kit's gyroscopes lag its accelerometers [s], as its hello or the
    #: uploaded file's header declared it (docs/extensions/gyro-delay.md); None: not declared
    gyro_delay_s: Mapped[float | None] = mapped_column(Float)

    streams: Mapped[list[Stream]] = relationship(back_populates="session",
                                                 cascade="all, delete-orphan")


class KitGyroBias(Base):
    """A kit's memory of one sensor's gyroscope bias (docs/gyro-bias-memory.md): the last
    one stillness taught, learnt in session ``session_id`` (begun ``session_started_at``:
    an older session processed later never replaces it). Forgotten when the kit is
    removed (a new kit, re-paired, starts with none)."""

    __tablename__ = "kit_gyro_biases"

    device_id: Mapped[int] = mapped_column(
        ForeignKey("devices.id", ondelete="CASCADE"), primary_key=True)
    sensor: Mapped[str] = mapped_column(String(12), primary_key=True)
    bias_x: Mapped[float] = mapped_column(Float)
    bias_y: Mapped[float] = mapped_column(Float)
    bias_z: Mapped[float] = mapped_column(Float)
    learnt: Mapped[str] = mapped_column(String(12))
    still_s: Mapped[float] = mapped_column(Float)
    age_s: Mapped[float] = mapped_column(Float)
    session_id: Mapped[int | None] = mapped_column(
        ForeignKey("sessions.id", ondelete="SET NULL"))
    session_started_at: Mapped[datetime] = mapped_column(UtcDateTime)
    updated_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)


class Stream(Base):
    """An ingest stream (``docs/spec/ingest.md``): its id, and the next ``seq`` it expects,
    committed with the data so a resume after a crash starts where the store ends."""

    __tablename__ = "streams"

    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    device_id: Mapped[int | None] = mapped_column(
        ForeignKey("devices.id", ondelete="SET NULL"))
    next_seq: Mapped[int] = mapped_column(BigInteger, default=0)
    last_t: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)

    session: Mapped[Session] = relationship(back_populates="streams")


class SampleBlock(Base):
    """Consecutive rows of one sensor: ``data`` is float64 (n, 10) little-endian,
    columns t, ax, ay, az, gx, gy, gz, mx, my, mz (NaN magnetometer on a 6-axis sensor),
    zlib-compressed. ``ordinal`` orders a sensor's blocks in time."""

    __tablename__ = "sample_blocks"
    __table_args__ = (Index("ix_sample_blocks_session_sensor", "session_id", "sensor",
                            "ordinal"),)

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"),
                                    primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    sensor: Mapped[str] = mapped_column(String(12))
    ordinal: Mapped[int] = mapped_column(BigInteger)
    n_rows: Mapped[int] = mapped_column(Integer)
    t_first: Mapped[float] = mapped_column(Float)
    t_last: Mapped[float] = mapped_column(Float)
    data: Mapped[bytes] = mapped_column(LargeBinary)


class Mark(Base):
    """A stream's or file's mark (``npose``, ``tpose``, ``exercise:<name>``, ``end:…``)."""

    __tablename__ = "marks"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    t: Mapped[float] = mapped_column(Float)
    label: Mapped[str] = mapped_column(String(120))


class EstimateBlock(Base):
    """Consecutive estimates of a session: float64 (n, len(columns)) zlib-compressed, the
    columns named in ``Session.estimate_columns`` (t [s], angles [rad], positions [m])."""

    __tablename__ = "estimate_blocks"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    ordinal: Mapped[int] = mapped_column(Integer)
    n_rows: Mapped[int] = mapped_column(Integer)
    data: Mapped[bytes] = mapped_column(LargeBinary)


class PatientTarget(Base):
    """A therapist's prescription for one patient: the range one joint angle should reach
    [deg] (``docs/spec/kinematics.md`` names and signs). One row per patient and angle."""

    __tablename__ = "patient_targets"
    __table_args__ = (UniqueConstraint("patient_id", "angle",
                                       name="uq_patient_targets_patient_angle"),
                      never_reused())

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(
        ForeignKey("patients.id", ondelete="CASCADE"), index=True)
    angle: Mapped[str] = mapped_column(String(40))
    min_deg: Mapped[float] = mapped_column(Float)
    max_deg: Mapped[float] = mapped_column(Float)
    note: Mapped[str | None] = mapped_column(String(500))
    updated_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)


class PatientTargetVersion(Base):
    """Every setting and removal of a patient's target, never changed afterwards: the
    target in force at a moment is the angle's last version set at or before it
    (``reports/targets.py``), so a report of last month keeps last month's target.
    ``min_deg``/``max_deg`` ``None``: the target was removed then."""

    __tablename__ = "patient_target_versions"
    __table_args__ = (Index("ix_patient_target_versions_patient_angle_set", "patient_id",
                            "angle", "set_at"),
                      {"sqlite_autoincrement": True})

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(
        ForeignKey("patients.id", ondelete="CASCADE"))
    angle: Mapped[str] = mapped_column(String(40))
    min_deg: Mapped[float | None] = mapped_column(Float)
    max_deg: Mapped[float | None] = mapped_column(Float)
    note: Mapped[str | None] = mapped_column(String(500))
    set_at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow)
    #: the therapist who set it (an id only: the version outlives the account)
    set_by: Mapped[int | None] = mapped_column(Integer)


class PasswordReset(Base):
    """A one-time password reset an admin issued: the SHA-256 of its token."""

    __tablename__ = "password_resets"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    therapist_id: Mapped[int] = mapped_column(
        ForeignKey("therapists.id", ondelete="CASCADE"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    issued_by: Mapped[int | None] = mapped_column(Integer)
    expires_at: Mapped[datetime] = mapped_column(UtcDateTime)
    used_at: Mapped[datetime | None] = mapped_column(UtcDateTime)


class AuditEntry(Base):
    """Who did what with which patient's data, when, from where. No foreign keys: an entry
    outlives the patient, session or device it names (erasures are logged too), and it
    holds ids only, never a patient's name or data."""

    __tablename__ = "audit_log"
    __table_args__ = never_reused()

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(UtcDateTime, default=utcnow, index=True)
    therapist_id: Mapped[int | None] = mapped_column(Integer, index=True)
    device_id: Mapped[int | None] = mapped_column(Integer)
    action: Mapped[str] = mapped_column(String(24))
    patient_id: Mapped[int | None] = mapped_column(Integer, index=True)
    session_id: Mapped[int | None] = mapped_column(Integer)
    route: Mapped[str] = mapped_column(String(300))
    client: Mapped[str | None] = mapped_column(String(64))


class Program(Base):
    """An exercise program prescribed for one patient (``docs/programs.md``); what it
    prescribes is in its versions. ``ended_at``: ended by the therapist (kept, with its
    history)."""

    __tablename__ = "programs"
    __table_args__ = (UniqueConstraint("patient_id", "name", name="uq_programs_patient_name"),
                      {"sqlite_autoincrement": True})

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(
        ForeignKey("patients.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(Name(120))
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)
    ended_at: Mapped[datetime | None] = mapped_column(UtcDateTime)

    versions: Mapped[list[ProgramVersion]] = relationship(
        back_populates="program", order_by="ProgramVersion.number",
        cascade="all, delete-orphan")


class ProgramVersion(Base):
    """One version of a program, never changed once saved: its dates (inclusive, in the
    clinic's time zone), note and ordered exercises. In force from ``created_at`` until
    the next version's."""

    __tablename__ = "program_versions"
    __table_args__ = (UniqueConstraint("program_id", "number",
                                       name="uq_program_versions_program_number"),
                      {"sqlite_autoincrement": True})

    id: Mapped[int] = mapped_column(primary_key=True)
    program_id: Mapped[int] = mapped_column(
        ForeignKey("programs.id", ondelete="CASCADE"), index=True)
    number: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)
    #: the therapist who saved it (no foreign key: the record outlives the account)
    created_by: Mapped[int | None] = mapped_column(Integer)
    start_date: Mapped[date] = mapped_column(Date)
    end_date: Mapped[date | None] = mapped_column(Date)
    note: Mapped[str | None] = mapped_column(String(2000))

    program: Mapped[Program] = relationship(back_populates="versions")
    exercises: Mapped[list[ProgramExercise]] = relationship(
        order_by="ProgramExercise.position", cascade="all, delete-orphan")


class ProgramExercise(Base):
    """One exercise of a version: a catalogue exercise, its angle, and its dose. Target
    [deg] ``None``: the patient's target for the angle applies, else the catalogue's."""

    __tablename__ = "program_exercises"
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(primary_key=True)
    version_id: Mapped[int] = mapped_column(
        ForeignKey("program_versions.id", ondelete="CASCADE"), index=True)
    position: Mapped[int] = mapped_column(Integer)
    exercise: Mapped[str] = mapped_column(String(40))
    angle: Mapped[str] = mapped_column(String(40))
    sets: Mapped[int] = mapped_column(Integer)
    repetitions: Mapped[int] = mapped_column(Integer)
    target_min_deg: Mapped[float | None] = mapped_column(Float)
    target_max_deg: Mapped[float | None] = mapped_column(Float)
    hold_s: Mapped[float] = mapped_column(Float)
    rest_s: Mapped[float] = mapped_column(Float)
    days_per_week: Mapped[int] = mapped_column(Integer)
    note: Mapped[str | None] = mapped_column(String(500))


class SessionProgram(Base):
    """The program version a session followed because its kit named the program in
    ``hello`` (``docs/extensions/programs-hello.md``); never changed afterwards."""

    __tablename__ = "session_programs"

    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), primary_key=True)
    version_id: Mapped[int] = mapped_column(
        ForeignKey("program_versions.id", ondelete="CASCADE"), index=True)


class SessionRating(Base):
    """Effort (Borg CR10, 0–10) and pain (numeric rating scale, 0–10) the patient gave
    after an exercise (``docs/extensions/effort-pain.md``). ``rating_id``: the kit's own
    id of the message, so that a message sent again is stored once."""

    __tablename__ = "session_ratings"
    __table_args__ = (UniqueConstraint("session_id", "rating_id",
                                       name="uq_session_ratings_session_rating"),
                      {"sqlite_autoincrement": True})

    id: Mapped[int] = mapped_column(primary_key=True)
    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    rating_id: Mapped[str] = mapped_column(String(64))
    exercise: Mapped[str] = mapped_column(String(120))
    t: Mapped[float | None] = mapped_column(Float)
    effort: Mapped[float | None] = mapped_column(Float)
    pain: Mapped[int | None] = mapped_column(Integer)
    received_at: Mapped[datetime] = mapped_column(UtcDateTime)
