"""Batch processing of a stored session: its recording through the estimator, the
estimates stored as blocks with the estimator version and settings they came from.
The same numbers as ``armtrack estimate`` on the session's exported recording (with
``--gyro-bias-in`` of the session's ``estimator.gyro_bias_prior``, when it has one)."""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np
from armtrack.estimator.arm.joints import SEGMENTS
from armtrack.estimator.errors import EstimatorError
from armtrack.estimator.metrics.assumptions import assumption_warnings
from armtrack.estimator.metrics.rom import CALIBRATION_TAIL_S
from armtrack.estimator.orientation import BIAS_PRIOR_FILTERS, DEFAULT_FILTER
from armtrack.estimator.pipeline import Calibration, Estimates, run_recording
from armtrack.estimator.pipeline.quality import residual_warnings
from armtrack.estimator.recording import Recording
from armtrack.estimator.recording.mismatch import recording_mismatch
from armtrack.estimator.rotations import matrix_to_quat
from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session as DbSession
from sqlalchemy.orm import sessionmaker

from .. import clock
from ..db import models
from .blocks import pack, unpack_many
from .gyro_bias import remember_session, session_priors
from .recordings import session_recording

#: Estimates per stored block.
ESTIMATE_BLOCK_ROWS = 6000


def here(work: Callable[..., Any], *args: Any) -> Any:
    """Run ``work(*args)`` on this thread (``process_session``'s default ``compute``)."""
    return work(*args)


def estimator_version() -> str:
    try:
        return version("armtrack")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def estimate_table(estimates: Estimates) -> tuple[list[str], np.ndarray]:
    """``armtrack estimate``'s columns, then each segment's orientation in the world as a
    quaternion (``<segment>_qw … _qz``, segment to world ENU)."""
    columns, values = estimates.table()
    quats = [matrix_to_quat(estimates.R_world_segment[s]) if len(estimates)
             else np.zeros((0, 4)) for s in SEGMENTS]
    columns = columns + [f"{s}_q{c}" for s in SEGMENTS for c in "wxyz"]
    return columns, np.column_stack([values, *quats])


def process_session(db: DbSession, session_id: int, filter_name: str = DEFAULT_FILTER,
                    compute: Callable[..., Any] = here) -> None:
    """Estimate a session from its stored samples and store the result, replacing any
    earlier estimates (committed). A recording the estimator refuses is recorded in
    ``processing_error``; the raw data stay. ``compute(work, *args)`` runs the estimation
    (here by default; the processing child runs it on a thread of lowest priority).

    The samples are read and estimated before anything is written, so the write
    transaction (which on SQLite holds the database's one write lock, and with it every
    live stream's group commit and ack) lasts only for the writes, not for the
    estimation's seconds."""
    session = db.get(models.Session, session_id)
    if session is None:
        return
    priors = session_priors(session) if filter_name in BIAS_PRIOR_FILTERS else None
    try:
        recording = session_recording(db, session)
        calibration, columns, blocks, warnings, elbow, learnt = compute(
            _estimated_blocks, recording, filter_name, session_id, priors)
    except EstimatorError as exc:
        db.execute(delete(models.EstimateBlock)
                   .where(models.EstimateBlock.session_id == session_id))
        # a session whose kit sent nothing: said so, not the estimator's "got ()"
        session.processing_error = (str(exc) if session.samples
                                    else "the session holds no samples: there is nothing "
                                         "to estimate")
        session.estimator = {"version": estimator_version(), "filter": filter_name}
        db.commit()
        return
    patient = db.get(models.Patient, session.patient_id)
    if patient is not None:  # an uploaded file whose body differs from the record
        warnings = [*record_mismatch_warnings(recording, patient), *warnings]
    # the writes, in one short transaction
    db.execute(delete(models.EstimateBlock).where(models.EstimateBlock.session_id == session_id))
    if blocks:
        db.execute(models.EstimateBlock.__table__.insert(), blocks)
    session.calibration = {
        "method": calibration.method,
        "final_time_s": calibration.final_time_s,
        "poses": [{"name": p.name, "start": p.start, "end": p.end}
                  for p in recording.calibration],
        "warnings": warnings,
        # the forearm sensor's +Y in the forearm's frame: its accelerometer's axis, which
        # the report's elbow pivot needs (estimator/metrics/elbow_pivot.py)
        **({"forearm_sensor_y": [float(v) for v in calibration.R_sensor_segment["forearm"][1]]}
           if "forearm" in calibration.R_sensor_segment else {}),
    }
    session.estimator = {"version": estimator_version(), "filter": filter_name,
                         **({"elbow": elbow} if elbow else {}),
                         **({"gyro_bias_prior": session.gyro_bias_prior} if priors else {})}
    session.estimate_columns = columns
    session.processing_error = None
    # the biases its stillness taught: the kit's next session starts from them
    remember_session(db, session, learnt)
    db.commit()


def record_mismatch_warnings(recording: Recording, patient: models.Patient) -> list[str]:
    """A warning in words when the session's side or body height (an uploaded file's
    header) differs from the patient's record: it was processed as the file says, and the
    therapist decides which is right (edit the record, or upload again with the record's)."""
    problems = recording_mismatch(recording, patient.side, patient.height_m)
    if not problems:
        return []
    return ["This recording differs from the patient's record: " + "; ".join(problems)
            + ". It was processed as the file says; if the record is right, upload the file "
            "again with the record's side and height (the upload dialog offers it), or "
            "correct the record."]


def _estimated_blocks(recording: Recording, filter_name: str, session_id: int,
                      priors: dict | None = None
                      ) -> tuple[Calibration, list[str], list[dict], list[str], dict | None,
                                 dict]:
    """The CPU work of ``process_session``: the estimates of ``recording`` (its filters
    started from the gyroscope bias ``priors``) as the estimate table's columns and packed
    blocks, with the calibration and its warnings, (a session with wrist points) what
    made its elbow (:func:`elbow_source`), and the filters' learnt gyroscope biases."""
    pipeline = run_recording(recording, filter_name, priors)
    estimates, calibration = pipeline.finish(), pipeline.calibration
    assert calibration is not None
    columns, values = estimate_table(estimates)
    blocks = [{"session_id": session_id, "ordinal": i, "n_rows": len(part), "data": pack(part)}
              for i, part in enumerate(np.array_split(
                  values, max(1, -(-len(values) // ESTIMATE_BLOCK_ROWS))))
              if len(part)]
    warnings = [w.message for w in calibration.warnings]
    warnings += [w.message for w in residual_warnings(estimates, tuple(recording.sensors))]
    warnings += assumption_warnings(estimates.t, estimates.residuals,
                                    tuple(recording.sensors),
                                    calibration.final_time_s + CALIBRATION_TAIL_S)
    return (calibration, columns, blocks, warnings, elbow_source(pipeline),
            pipeline.learnt_biases())


def elbow_source(pipeline) -> dict[str, Any] | None:
    """What made a session's elbow when it had wrist points (``docs/extensions/points.md``):
    ``source`` (``points`` or ``imu``), the shares of samples whose heading was held
    (``held_share``) and without a point (``no_point_share``), and with a forearm IMU the
    RMS difference of the two elbow flexions (``disagreement_deg``); None without points."""
    gamma = pipeline.gamma
    if gamma is None or not gamma.stats.samples:
        return None
    stats = gamma.stats
    return {"source": gamma.source, "held_share": round(stats.flagged_share, 4),
            "no_point_share": round(stats.no_point / stats.samples, 4),
            "disagreement_deg": None if stats.disagreement_rms_deg is None
            else round(stats.disagreement_rms_deg, 3)}


def stored_estimates(db: DbSession, session: models.Session) -> tuple[list[str], np.ndarray]:
    """The stored estimate table of a session (columns, (n, k) values); empty if none."""
    columns = list(session.estimate_columns or [])
    blobs = db.scalars(select(models.EstimateBlock.data)
                       .where(models.EstimateBlock.session_id == session.id)
                       .order_by(models.EstimateBlock.ordinal)).all()
    return columns, unpack_many(list(blobs), len(columns)) if columns else np.empty((0, 0))


def mark_closed(db: DbSession, session_id: int) -> bool | None:
    """A live or interrupted session becomes closed, ended now (committed): True; False
    when it was closed already (by another instance, a kit's ``bye``), None when it is
    gone. One statement, so of closes at once (any instances) exactly one gets True."""
    changed = db.execute(update(models.Session)
                         .where(models.Session.id == session_id,
                                models.Session.status != "closed")
                         .values(status="closed", ended_at=clock.now())).rowcount
    db.commit()
    if changed:
        return True
    return False if db.get(models.Session, session_id) is not None else None


def process_in_background(factory: sessionmaker, session_id: int, filter_name: str,
                          compute: Callable[..., Any] = here) -> None:
    with factory() as db:
        process_session(db, session_id, filter_name, compute)
