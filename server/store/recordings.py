"""A stored session as a recording (``spec/recording.md``) and a recording as a stored
session. Stored rows are the float64 numbers parsed from the file or the stream, so an
export reads back to exactly them."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.calibration.plan import poses_from_marks
from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.recording import Mark, Pose, Recording, SensorStream
from armtrack.estimator.recording.model import check_metadata
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from ..db import models
from .blocks import SAMPLE_COLUMNS, pack, unpack_many

#: Mark labels that delimit calibration poses (they become the ``calibration`` header).
POSE_LABELS = frozenset({"npose", "end:npose", "tpose", "end:tpose"})
#: Rows per stored block of an uploaded file.
UPLOAD_BLOCK_ROWS = 1000


def sensor_rows(stream: SensorStream) -> np.ndarray:
    """A sensor's samples as (n, 10) rows t, acc, gyr, mag (NaN magnetometer if 6-axis)."""
    mag = stream.mag if stream.mag is not None else np.full((len(stream), 3), np.nan)
    return np.column_stack([stream.t, stream.acc, stream.gyr, mag])


def pose_marks(poses: Iterable[Pose]) -> list[Mark]:
    """Calibration poses as the marks a stream would have sent."""
    return [m for p in poses for m in (Mark(p.start, p.name), Mark(p.end, f"end:{p.name}"))]


def add_recording(db: DbSession, patient: models.Patient, recording: Recording,
                  device_id: int | None = None) -> models.Session:
    """Store an uploaded recording as a new closed session (not committed)."""
    session = models.Session(
        patient_id=patient.id, device_id=device_id, source="upload", status="closed",
        side=recording.side, height_m=recording.height_m,
        lengths=recording.lengths.as_dict() if recording.lengths else None,
        rate_hz=recording.rate_hz,
        sensors={n: {"nine_axis": s.nine_axis} for n, s in recording.sensors.items()},
        meta=dict(recording.metadata),
        samples=sum(len(s) for s in recording.sensors.values()))
    db.add(session)
    db.flush()
    blocks = []
    for name, stream in recording.sensors.items():
        rows = sensor_rows(stream)
        for ordinal, start in enumerate(range(0, len(rows), UPLOAD_BLOCK_ROWS)):
            part = rows[start:start + UPLOAD_BLOCK_ROWS]
            blocks.append({"session_id": session.id, "sensor": name, "ordinal": ordinal,
                           "n_rows": len(part), "t_first": float(part[0, 0]),
                           "t_last": float(part[-1, 0]), "data": pack(part)})
    if blocks:
        db.execute(models.SampleBlock.__table__.insert(), blocks)
    for mark in (*pose_marks(recording.calibration), *recording.marks):
        db.add(models.Mark(session_id=session.id, t=mark.t, label=mark.label))
    session.ended_at = session.started_at
    return session


def session_recording(db: DbSession, session: models.Session) -> Recording:
    """The session's raw data as a recording: every stored sample, the calibration poses
    its marks delimit and its exercise marks."""
    streams = {}
    for name, info in session.sensors.items():
        blobs = db.scalars(
            select(models.SampleBlock.data)
            .where(models.SampleBlock.session_id == session.id,
                   models.SampleBlock.sensor == name)
            .order_by(models.SampleBlock.ordinal)).all()
        rows = unpack_many(list(blobs), len(SAMPLE_COLUMNS))
        if not len(rows):
            continue  # named by the kit but never sent a sample
        streams[name] = SensorStream(rows[:, 0], rows[:, 1:4], rows[:, 4:7],
                                     rows[:, 7:10] if info.get("nine_axis", True) else None)
    marks = [Mark(m.t, m.label) for m in db.scalars(
        select(models.Mark).where(models.Mark.session_id == session.id)
        .order_by(models.Mark.t, models.Mark.id))]
    return Recording(
        side=session.side, sensors=streams, height_m=session.height_m,
        lengths=SegmentLengths(**session.lengths) if session.lengths else None,
        calibration=tuple(poses_from_marks(m for m in marks if m.label in POSE_LABELS)),
        marks=tuple(m for m in marks if m.label not in POSE_LABELS),
        rate_hz=session.rate_hz, metadata=header_metadata(session.meta or {}))


def header_metadata(meta: dict) -> dict[str, str]:
    """The session's metadata a recording header can carry: each value on one line,
    spaces collapsed (a kit's ``hello`` name may hold a line break or end in a space,
    which made every export of its sessions fail); keys a header cannot carry are left
    out."""
    out = {}
    for key, value in meta.items():
        value = " ".join(str(value).split())
        try:
            check_metadata(key, value)
        except InvalidArgument:
            continue
        out[key] = value
    return out
