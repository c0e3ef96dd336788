"""A stored session as a recording (``docs/spec/recording.md``) and a recording as a stored
session. Stored rows are the float64 numbers parsed from the file or the stream, so an
export reads back to exactly them."""

from __future__ import annotations

from collections.abc import Iterable
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from armtrack.estimator.arm.coverage import coverage
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.calibration.plan import poses_from_marks
from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.recording import Mark, Pose, Recording, SensorStream
from armtrack.estimator.recording.model import GYRO_DELAY_KEY, check_metadata
from armtrack.estimator.recording.points import POINT_NAMES, POINTS_HEADER_KEYS, PointStream
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models
from ..ingest.carried_on import KEY as CARRIES_ON_KEY
from ..ingest.points import POINT_PREFIX, frame_from_meta, frame_to_meta
from ..spreadsheet import header_text
from ..text_direction import shown
from .blocks import SAMPLE_COLUMNS, pack, unpack_many
from .gyro_bias import session_prior

#: Mark labels that delimit calibration poses (they become the ``calibration`` header).
POSE_LABELS = frozenset({"npose", "end:npose", "tpose", "end:tpose"})
#: Rows per stored block of an uploaded file.
UPLOAD_BLOCK_ROWS = 1000
#: The header that dates a recording (``docs/extensions/start-time.md``).
START_TIME_KEY = "start_time"
#: Most characters of a recording header's metadata (its keys and values together) a
#: session keeps: every listing of the patient's sessions carries them (a kit's six
#: uploads with a 50 MB value made that listing 161 MB and 8.2 s). Real headers hold
#: ~150.
MAX_METADATA_CHARS = 16_000


def metadata_problem(recording: Recording) -> str | None:
    """What is wrong with the size of ``recording``'s header metadata, or None."""
    size = sum(len(k) + len(v) for k, v in recording.metadata.items())
    if size <= MAX_METADATA_CHARS:
        return None
    return (f"the header's metadata holds {size:,} characters ({len(recording.metadata):,} "
            f"keys), more than a session keeps ({MAX_METADATA_CHARS:,}): remove or shorten "
            "header lines")


def marks_problem(recording: Recording) -> str | None:
    """What is wrong with ``recording``'s marks, or None: a stream's session keeps at most
    ``MARKS_PER_SESSION_MAX`` marks of labels of at most ``MARK_LABEL_MAX`` characters,
    and an upload's the same. (Its ``marks`` header was kept whole: a kit's 47 MB upload of
    200,000 marks took 25.5 s to store, its first summary 31 s and +347 MB of the server,
    the summary 29 MB on each opening of the session page.)"""
    from ..ingest.endpoint import MARKS_PER_SESSION_MAX
    from ..ingest.protocol import MARK_LABEL_MAX

    if len(recording.marks) > MARKS_PER_SESSION_MAX:
        return (f"the header holds {len(recording.marks):,} marks, more than a session "
                f"keeps ({MARKS_PER_SESSION_MAX:,}, as a kit's stream): split the recording "
                "or leave marks out")
    longest = max(recording.marks, key=lambda m: len(m.label), default=None)
    if longest is not None and len(longest.label) > MARK_LABEL_MAX:
        return (f"the mark at t = {longest.t:g} s has a label of {len(longest.label):,} "
                f"characters, more than a mark may ({MARK_LABEL_MAX}, as a kit's stream): "
                "shorten it")
    return None


def header_text_problem(recording: Recording) -> str | None:
    """What is wrong with the text of ``recording``'s header metadata values, or None: each
    is one line of text the pages, reports and exports show, so it holds no control
    character and no direction control (``plain_text.text_problem``: "left\u202ethgir"
    shows as "leftright"), as a name or a kit's hello may not. (Mark labels are held to
    ``npose``, ``tpose``, ``exercise:<name>`` and ``end:<label>`` by the reader.)"""
    from ..plain_text import text_problem

    for key, value in recording.metadata.items():
        if (problem := text_problem(str(value))) is not None:
            return f"header {key!r} must be valid text: {problem}"
    return None


def recorded_start(recording: Recording) -> datetime | None:
    """When the recording's ``t = 0`` was, from its ``start_time`` header (ISO 8601 with a
    time zone; ``docs/extensions/start-time.md``), in UTC; ``None`` without the header.
    Raises InvalidArgument naming the header when it is not such a moment."""
    text = recording.metadata.get(START_TIME_KEY)
    if text is None:
        return None
    try:
        moment = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InvalidArgument(f"header {START_TIME_KEY}: {text!r} is not an ISO 8601 date "
                              "and time (2026-12-01T09:30:00+01:00)") from None
    if moment.tzinfo is None:
        raise InvalidArgument(f"header {START_TIME_KEY}: {text!r} has no time zone; add "
                              "one (+01:00, or Z for UTC)")
    moment = moment.astimezone(UTC)
    if moment > datetime.now(UTC) + timedelta(days=1):
        raise InvalidArgument(f"header {START_TIME_KEY}: {text!r} is in the future")
    return moment


def dated_by(session: models.Session) -> str:
    """What the session's ``started_at`` is: ``recorded`` (the file's ``start_time``
    header), ``uploaded`` (an upload without one: the time it arrived) or ``streamed``
    (when the kit's stream started)."""
    if session.source != "upload":
        return "streamed"
    return "recorded" if START_TIME_KEY in (session.meta or {}) else "uploaded"


def sensor_rows(stream: SensorStream) -> np.ndarray:
    """A sensor's samples as (n, 10) rows t, acc, gyr, mag (NaN magnetometer if 6-axis)."""
    mag = stream.mag if stream.mag is not None else np.full((len(stream), 3), np.nan)
    return np.column_stack([stream.t, stream.acc, stream.gyr, mag])


def point_rows(points: PointStream) -> np.ndarray:
    """A point's positions as stored rows: t, x, y, z and six NaN (n, 10)."""
    rows = np.full((len(points), len(SAMPLE_COLUMNS)), np.nan)
    rows[:, 0], rows[:, 1:4] = points.t, points.p
    return rows


def pose_marks(poses: Iterable[Pose]) -> list[Mark]:
    """Calibration poses as the marks a stream would have sent."""
    return [m for p in poses for m in (Mark(p.start, p.name), Mark(p.end, f"end:{p.name}"))]


def upload_blocks(recording: Recording) -> list[dict[str, Any]]:
    """The recording's sample blocks, packed, as ``add_recording`` inserts them (without
    their session): made before the transaction writes anything, so the database's write
    lock (SQLite has one for every stream) is not held while they are compressed."""
    tables = [(name, sensor_rows(stream)) for name, stream in recording.sensors.items()]
    tables += [(POINT_PREFIX + name, point_rows(points))
               for name, points in recording.points.items()]
    blocks = []
    for name, rows in tables:
        for ordinal, start in enumerate(range(0, len(rows), UPLOAD_BLOCK_ROWS)):
            part = rows[start:start + UPLOAD_BLOCK_ROWS]
            blocks.append({"sensor": name, "ordinal": ordinal,
                           "n_rows": len(part), "t_first": float(part[0, 0]),
                           "t_last": float(part[-1, 0]), "data": pack(part)})
    return blocks


def add_recording(db: DbSession, patient: models.Patient, recording: Recording,
                  device_id: int | None = None,
                  blocks: list[dict[str, Any]] | None = None) -> models.Session:
    """Store an uploaded recording as a new closed session (not committed), dated when it
    was recorded (``start_time`` header), else when it arrived; ``blocks``: its
    ``upload_blocks`` made already. Raises InvalidArgument for a ``start_time`` that is
    not an ISO 8601 moment with a zone."""
    start = recorded_start(recording)
    if blocks is None:
        blocks = upload_blocks(recording)  # before the session's insert takes the lock
    session = models.Session(
        patient_id=patient.id, device_id=device_id, source="upload", status="closed",
        side=recording.side, height_m=recording.height_m,
        lengths=recording.lengths.as_dict() if recording.lengths else None,
        rate_hz=recording.rate_hz,
        sensors={n: {"nine_axis": s.nine_axis} for n, s in recording.sensors.items()},
        meta={**{k: v for k, v in recording.metadata.items() if k != GYRO_DELAY_KEY},
              **coverage(recording.sensors)},
        # rows of all sensors and points together, as a stream's writer counts them
        # (ARMTRACK_MAX_SESSION_SAMPLES, the kit's day: kit/daily_samples.py)
        samples=sum(len(s) for s in recording.sensors.values())
        + sum(len(p) for p in recording.points.values()),
        created_at=clock.now(),
        # a kit's own upload (recorded offline) starts from the kit's memory too
        gyro_bias_prior=session_prior(db, device_id),
        gyro_delay_s=(recording.gyro_delay_s if GYRO_DELAY_KEY in recording.metadata
                      else None))
    if start is not None:
        session.started_at = start
    if recording.points_frame is not None:  # docs/extensions/points.md
        session.meta = {**session.meta, **frame_to_meta(recording.points_frame)}
    db.add(session)
    db.flush()
    if blocks:
        db.execute(models.SampleBlock.__table__.insert(),
                   [{"session_id": session.id, **block} for block in blocks])
    for mark in (*pose_marks(recording.calibration), *recording.marks):
        db.add(models.Mark(session_id=session.id, t=mark.t, label=mark.label))
    ends = [float(s.t[-1] - s.t[0]) for s in recording.sensors.values() if len(s)]
    # (a sample means a block: the block loop's ``start`` made ``start is not None`` here)
    session.ended_at = (session.started_at + timedelta(seconds=max(ends))
                        if ends else session.started_at)
    return session


def session_recording(db: DbSession, session: models.Session) -> Recording:
    """The session's raw data as a recording: every stored sample, the calibration poses
    its marks delimit and its exercise marks."""
    streams = {}
    for name, info in session.sensors.items():
        rows = _stored_rows(db, session.id, name)
        if not len(rows):
            continue  # named by the kit but never sent a sample
        streams[name] = SensorStream(rows[:, 0], rows[:, 1:4], rows[:, 4:7],
                                     rows[:, 7:10] if info.get("nine_axis", True) else None)
    frame = frame_from_meta(session.meta or {})
    points = {}
    if frame is not None:
        for name in POINT_NAMES:
            rows = _stored_rows(db, session.id, POINT_PREFIX + name)
            if len(rows):
                points[name] = PointStream(rows[:, 0], rows[:, 1:4])
    marks = [Mark(m.t, m.label) for m in db.scalars(
        select(models.Mark).where(models.Mark.session_id == session.id)
        .order_by(models.Mark.t, models.Mark.id))]
    return Recording(
        side=session.side, sensors=streams, height_m=session.height_m,
        lengths=SegmentLengths(**session.lengths) if session.lengths else None,
        calibration=tuple(poses_from_marks(m for m in marks if m.label in POSE_LABELS)),
        marks=tuple(m for m in marks if m.label not in POSE_LABELS),
        rate_hz=session.rate_hz,
        metadata={**header_metadata(session.meta or {}), **delay_metadata(session)},
        points=points, points_frame=frame if points else None)


def session_lengths(session: models.Session) -> SegmentLengths:
    """The body a session's estimates use (``Recording.segment_lengths`` of its stored
    recording): its measured segment lengths, else those of its height."""
    if session.lengths:
        return SegmentLengths(**session.lengths)
    return SegmentLengths.from_height(session.height_m)


def delay_metadata(session: models.Session) -> dict[str, str]:
    """The ``gyro_delay_s`` header of the session's declared gyroscope delay
    (docs/extensions/gyro-delay.md), as the session keeps it; empty when none was."""
    if session.gyro_delay_s is None:
        return {}
    return {GYRO_DELAY_KEY: repr(float(session.gyro_delay_s))}


def _stored_rows(db: DbSession, session_id: int, sensor: str) -> np.ndarray:
    """Every stored row of one sensor (or point) of a session, in order, (n, 10)."""
    blobs = db.scalars(
        select(models.SampleBlock.data)
        .where(models.SampleBlock.session_id == session_id, models.SampleBlock.sensor == sensor)
        .order_by(models.SampleBlock.ordinal)).all()
    return unpack_many(list(blobs), len(SAMPLE_COLUMNS))


def header_metadata(meta: dict) -> dict[str, str]:
    """The session's metadata a recording header can carry: each value on one line,
    spaces collapsed (a kit's ``hello`` name may hold a line break or end in a space,
    which made every export of its sessions fail); keys a header cannot carry are left
    out."""
    out = {}
    for key, value in meta.items():
        if key in POINTS_HEADER_KEYS:
            continue  # the points extension's own header (docs/extensions/points.md)
        if key == GYRO_DELAY_KEY:
            continue  # the session's own column (delay_metadata)
        if isinstance(value, dict | list):  # the server's own notes (measured angles)
            continue
        if key == CARRIES_ON_KEY and isinstance(value, int):  # the server's own link to a
            continue  # session of its own (an uploaded header's text line is kept)
        # one line, and no cell a spreadsheet splits off it starts a formula: the kit's text
        value = header_text(" ".join(shown(str(value)).split()))
        try:
            check_metadata(key, value)
        except InvalidArgument:
            continue
        out[key] = value
    return out
