"""Sessions: lists, details, closing, erasing, uploads of recorded files and exports of
the raw data (a recording file) and the estimates (``armtrack estimate``'s CSV)."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Annotated, Literal

from anyio import from_thread
from armtrack.estimator.errors import EstimatorError, InvalidArgument
from armtrack.estimator.orientation import DEFAULT_FILTER
from armtrack.estimator.recording import parse_recording, write_recording_to
from fastapi import APIRouter, Depends, Form, HTTPException, Request, UploadFile, status
from fastapi.responses import Response
from pydantic import TypeAdapter
from sqlalchemy import select, text
from sqlalchemy.orm import Session as DbSession
from sqlalchemy.orm import object_session

from .. import audit
from ..auth import hash_token
from ..commands.output import write_angles_csv
from ..db import models
from ..ingest import carried_on
from ..kit import daily_samples, discharge, new_sessions
from ..live.access import holds
from ..reports.content import no_estimates_words
from ..services import Services
from ..store.background import ProcessingFailed
from ..store.coverage import plain_metadata, session_coverage
from ..store.processing import (
    mark_closed,
    stored_estimates,
)
from ..store.recordings import (
    add_recording,
    dated_by,
    header_text_problem,
    marks_problem,
    metadata_problem,
    session_recording,
    upload_blocks,
)
from ..store.silence import closed_after_silence
from ..store.stopped import stopped_by_server
from .deps import (
    Db,
    Page,
    Therapist,
    current_therapist,
    in_export_turn,
    long_list,
    oauth2,
    own_patient,
    own_session,
    therapist_of_token,
)
from .deps import services as get_services
from .erase import erase_session
from .schemas import MAX_ID, Id, SessionOut
from .spool import as_text, spooled

router = APIRouter(prefix="/api", tags=["sessions"])

#: Columns of the angles export: those of ``armtrack estimate``.
ANGLE_COLUMNS_END = "hand_z"


def session_out(session: models.Session) -> SessionOut:
    db = object_session(session)
    device = (db.get(models.Device, session.device_id)
              if db is not None and session.device_id is not None else None)
    return SessionOut(
        id=session.id, patient_id=session.patient_id, device_id=session.device_id,
        device_name=device.name if device is not None else None,
        source=session.source, status=session.status, started_at=session.started_at,
        ended_at=session.ended_at, side=session.side, sensors=list(session.sensors),
        nine_axis={k: bool(v.get("nine_axis")) for k, v in session.sensors.items()},
        samples=session.samples, rate_hz=session.rate_hz, metadata=plain_metadata(session),
        **session_coverage(session), processed=bool(session.estimate_columns),
        calibration=session.calibration,
        estimator=session.estimator, processing_error=session.processing_error,
        dated=dated_by(session), stopped_by_server=stopped_by_server(session),
        carries_on=carried_on.carries_on(session),
        closed_after_silence=closed_after_silence(session))


_SESSIONS_JSON = TypeAdapter(list[SessionOut])


@router.get("/patients/{patient_id}/sessions", response_model=list[SessionOut])
def list_sessions(patient_id: Id, db: Db, therapist: Therapist,
                  page: Annotated[Page, Depends()]) -> Response:
    """A patient's sessions, newest first."""
    own_patient(db, therapist, patient_id)
    with long_list(therapist, page.limit):
        sessions = db.scalars(select(models.Session)
                              .where(models.Session.patient_id == patient_id)
                              .order_by(models.Session.started_at.desc(),
                                        models.Session.id.desc())
                              .limit(page.limit).offset(page.offset))
        # written as JSON here, while the list counts as the account's
        return Response(_SESSIONS_JSON.dump_json([session_out(s) for s in sessions]),
                        media_type="application/json")


@router.get("/sessions/{session_id}", response_model=SessionOut)
def get_session(session_id: Id, db: Db, therapist: Therapist) -> SessionOut:
    return session_out(own_session(db, therapist, session_id))


@router.post("/sessions/{session_id}/close", response_model=SessionOut,
             responses={202: {"model": SessionOut,
                              "description": "closed; its estimation follows (wait=false)"}})
async def close_session(session_id: Id, therapist: Therapist,
                        svc: Annotated[Services, Depends(get_services)],
                        response: Response, wait: bool = True) -> SessionOut:
    """Close a live or interrupted session (a live stream is ended) and estimate it: the
    answer waits for the estimation, or with ``wait=false`` (docs/extensions/
    close-without-wait.md) comes once the session is closed, 202, the estimation following
    (``processed`` turns true on ``GET /api/sessions/{id}``)."""
    session = await svc.run_db(lambda db: own_session(db, therapist, session_id))
    if session.status == "closed":
        raise HTTPException(status.HTTP_409_CONFLICT, f"session {session_id} is already closed")
    if session_id in svc.closing:  # closes at once (a double click): one closes, one estimates
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"session {session_id} is being closed already")
    svc.closing.add(session_id)
    try:
        await svc.end_session_streams(session_id, "session closed by the therapist")
        closed = await svc.run_db(mark_closed, session_id)
    finally:
        svc.closing.discard(session_id)
    if closed is None:  # erased meanwhile
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no session {session_id}")
    if not closed:  # another instance's close (or the kit's bye) came first: it estimates
        raise HTTPException(status.HTTP_409_CONFLICT, f"session {session_id} is already closed")
    estimation = svc.process_later(session_id, DEFAULT_FILTER)
    if not wait:
        response.status_code = status.HTTP_202_ACCEPTED
        response.headers["Location"] = f"/api/sessions/{session_id}"
    else:
        with contextlib.suppress(ProcessingFailed):  # logged; the session shows no estimates
            await estimation
    return await svc.run_db(_session_out_or_404, therapist, session_id)


def _session_out_or_404(db, therapist: models.Therapist, session_id: int) -> SessionOut:
    """The closed session, read again after the close's wait: 404 when it was erased
    meanwhile or is no longer the therapist's (the patient given to another, the account
    disabled), as every other route of the session answers them then."""
    fresh = db.get(models.Therapist, therapist.id)
    if fresh is None or fresh.disabled_at is not None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no session {session_id}")
    return session_out(own_session(db, fresh, session_id))


@router.delete("/sessions/{session_id}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_session(session_id: Id, therapist: Therapist,
                         svc: Annotated[Services, Depends(get_services)]) -> None:
    """Erase the session and all its data (an open stream of it is closed first, its
    replays after)."""
    await svc.run_db(lambda db: own_session(db, therapist, session_id))
    await svc.end_session_streams(session_id, "session erased")
    await svc.run_db(erase_session, session_id)
    svc.hub.forget_session(session_id)  # its last pose is no view's to draw any more
    await svc.access.recheck()


def uploader(db: Db, token: Annotated[str | None, Depends(oauth2)], request: Request
             ) -> models.Therapist | models.Device:
    """A therapist, or a device uploading for its own patient."""
    if token:
        device = db.scalar(select(models.Device).where(
            models.Device.token_hash == hash_token(token), models.Device.revoked_at.is_(None)))
        if device is not None:
            audit.note(device_id=device.id)
            return device
    return current_therapist(db, token, request)


@router.post("/recordings", response_model=SessionOut, status_code=status.HTTP_201_CREATED,
             responses={202: {"model": SessionOut,
                              "description": "stored; processing follows (wait=false)"}})
def upload_recording(db: Db, who: Annotated[models.Therapist | models.Device,
                                            Depends(uploader)],
                     svc: Annotated[Services, Depends(get_services)],
                     response: Response,
                     token: Annotated[str | None, Depends(oauth2)],
                     file: UploadFile | None = None,
                     patient_id: Annotated[int | None, Form(ge=1, le=MAX_ID)] = None,
                     files: list[UploadFile] | None = None,
                     sensors: Annotated[str | None, Form(max_length=20_000)] = None,
                     format: Annotated[str | None, Form(max_length=40)] = None,
                     calibration: Annotated[str | None, Form(max_length=500)] = None,
                     side: Annotated[Literal["right", "left"] | None, Form()] = None,
                     height_m: Annotated[float | None, Form(gt=0.5, lt=2.6)] = None,
                     options: Annotated[str | None, Form(max_length=2000)] = None,
                     wait: Annotated[bool, Form()] = True,
                     ) -> SessionOut:
    """A recording file (``docs/spec/recording.md``) recorded offline: stored as a new closed
    session and estimated. With a device token the patient is the device's own.

    Extension (docs/extensions/recordings-upload.md): vendor exports as ``files`` with a
    ``sensors`` map instead of ``file``; ``wait=false`` answers 202 once the session is
    stored, its processing followed at ``Location`` (``/api/recordings/{id}/progress``).
    A kit's upload is one of its new sessions: past ``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR``
    in the last hour, 429 naming the limit, nothing stored; while another upload of the
    kit is being stored, 429 saying so (``new_sessions.BUSY``), nothing stored."""
    from . import imports  # vendor importers load only when used

    if (file is None) == (not files):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "give either file (a recording) or files with a sensors map")
    if isinstance(who, models.Device):
        if patient_id is not None and patient_id != who.patient_id:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no patient {patient_id}")
        patient = db.get(models.Patient, who.patient_id)
        if patient is not None and (why := discharge.refusal(patient)) is not None:
            raise HTTPException(status.HTTP_403_FORBIDDEN, why)  # nothing is read
        device_id = who.id
        # a kit's upload is one of its new sessions (ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR):
        # counted, then stored, one upload of the kit at a time; one coming meanwhile is
        # refused at once rather than holding a worker thread while it waits
        one_at_a_time = new_sessions.one_upload_at_a_time(
            device_id, new_sessions.upload_lock_file(svc.engine))
    else:
        if patient_id is None:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                "patient_id is required with a therapist's token")
        patient = own_patient(db, who, patient_id)
        device_id = None
        one_at_a_time = contextlib.nullcontext(True)
    assert patient is not None
    with (imports.therapist_turn(who) if device_id is None else contextlib.nullcontext()), \
            one_at_a_time as taken:
        if not taken:
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, new_sessions.BUSY)
        try:
            session = _count_and_store(db, svc, patient, device_id, file, files, sensors,
                                       format, calibration, side, height_m, options,
                                       lambda: _right_gone(db, svc, who, token, patient.id))
        except BaseException:
            db.rollback()  # the kit's database turns go at once, whatever went wrong
            raise
    if device_id is not None:  # a stream of the kit open meanwhile counts it in its day
        from_thread.run_sync(svc.count_kit_samples, device_id, session.id,
                             session.created_at, session.samples)
    audit.note(patient_id=patient.id, session_id=session.id)
    # estimated where closed sessions are (store.background)
    job = imports.start_processing(svc, session.id)
    if not wait:
        response.status_code = status.HTTP_202_ACCEPTED
        response.headers["Location"] = f"/api/recordings/{session.id}/progress"
        return session_out(session)
    job.result()  # this thread waits for it
    db.refresh(session)
    return session_out(session)


#: Said when an upload's right went while it was read (``_right_gone``).
NOTHING_STORED = "nothing of the upload was stored"


def _right_gone(db: DbSession, svc: Services, who: models.Therapist | models.Device,
                token: str | None, patient_id: int) -> HTTPException | None:
    """Why the upload may no longer be stored, read again just before its session's
    insert with the rows held until its commit, or None. An upload is checked when its
    body has arrived, then read and parsed (seconds; an APDM ``.h5`` up to two minutes):
    a patient reassigned or erased meanwhile, an account disabled, a sign-in ended or a
    kit revoked had its session stored all the same, written by whoever no longer held
    the patient (tests/test_security_ingest.py). SQLite: the write lock, taken
    first, holds every other writer off until the commit; PostgreSQL: the rows read are
    held (``FOR SHARE``) until then."""
    if db.get_bind().dialect.name == "sqlite":  # a kit's count turn may hold it already
        db.execute(text("UPDATE patients SET name = name WHERE id = :p"), {"p": patient_id})

    def fresh(model, *where):
        return db.scalar(select(model).where(*where).with_for_update(read=True)
                         .execution_options(populate_existing=True))

    patient = fresh(models.Patient, models.Patient.id == patient_id)
    if isinstance(who, models.Device):
        device = fresh(models.Device, models.Device.id == who.id)
        if device is None or device.revoked_at is not None or patient is None \
                or device.patient_id != patient_id:
            return HTTPException(status.HTTP_401_UNAUTHORIZED,
                                 f"this kit was revoked while its upload was read: "
                                 f"{NOTHING_STORED}", headers={"WWW-Authenticate": "Bearer"})
        if (why := discharge.refusal(patient)) is not None:
            return HTTPException(status.HTTP_403_FORBIDDEN, f"{why} ({NOTHING_STORED})")
        return None
    fresh(models.AccessToken, models.AccessToken.token_hash == hash_token(token or ""))
    fresh(models.Therapist, models.Therapist.id == who.id)
    therapist = therapist_of_token(db, token, svc.settings.demo_mode)
    if therapist is None or therapist.id != who.id:
        return HTTPException(status.HTTP_401_UNAUTHORIZED,
                             f"your sign-in ended while the upload was read (signed out, "
                             f"the password changed or the account disabled): "
                             f"{NOTHING_STORED}; sign in again",
                             headers={"WWW-Authenticate": "Bearer"})
    if not holds(therapist, patient):
        return HTTPException(status.HTTP_404_NOT_FOUND,
                             f"no patient {patient_id}: {NOTHING_STORED} (the patient was "
                             "reassigned or erased while it was read)")
    return None


def _count_and_store(db, svc: Services, patient: models.Patient, device_id: int | None,
                     file: UploadFile | None, files: list[UploadFile] | None,
                     sensors: str | None, format: str | None, calibration: str | None,
                     side: str | None, height_m: float | None, options: str | None,
                     right_gone=lambda: None) -> models.Session:
    """The upload read and stored as a new closed session (committed). A kit's
    (``device_id``) is one of its new sessions: its upload turn across instances is taken
    for the whole transaction (429 ``BUSY`` at once when another instance has it), the
    count made before the file is read and again, in the kit's count turn, just before the
    session is stored, so a hello of the kit racing this upload cannot both pass."""
    from . import imports  # vendor importers load only when used

    limit = svc.settings.max_new_sessions_per_kit_hour
    if device_id is not None:
        db.commit()  # nothing written yet: what follows is one transaction
        if not new_sessions.upload_turn(db, device_id):
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, new_sessions.BUSY)
        why = new_sessions.refusal(db, device_id, limit)  # over the limit: nothing is read
        if why is not None:
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, why)
    if file is not None:
        try:
            recording = parse_recording(file.file.read())
        except EstimatorError as exc:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{file.filename or 'file'}: {exc}") from None
    else:
        if not sensors:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                "files need a sensors map (JSON: sensor → file name)")
        recording = imports.import_upload(files, sensors, patient, format, calibration,
                                          side, height_m, options,
                                          svc.settings.max_upload_bytes)
    if (why := metadata_problem(recording) or marks_problem(recording)
            or header_text_problem(recording)) is not None:
        name = (file.filename if file is not None else None) or "the files"
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{name}: {why}")
    held = sum(len(s) for s in recording.sensors.values()) \
        + sum(len(p) for p in recording.points.values())
    if held > svc.settings.max_session_samples:  # its estimation would hold every row
        name = (file.filename if file is not None else None) or "the files"
        raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                            f"{name}: the recording holds {held} samples, more than one "
                            f"session holds ({svc.settings.max_session_samples}, "
                            "ARMTRACK_MAX_SESSION_SAMPLES): split it into shorter sessions")
    if device_id is not None:  # the kit's day (its upload turn is held: one at a time)
        why = daily_samples.refusal(daily_samples.stored(db, device_id), held,
                                    svc.settings.max_kit_samples_per_day)
        if why is not None:
            name = (file.filename if file is not None else None) or "the files"
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, f"{name}: {why}")
    blocks = upload_blocks(recording)  # packed before the database's write lock is taken
    if device_id is not None:
        new_sessions.count_turn(db, device_id)  # a hello of the kit counts before or after
        why = new_sessions.refusal(db, device_id, limit)
        if why is not None:
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, why)
    if (gone := right_gone()) is not None:  # read again where no change can come between
        raise gone
    try:
        session = add_recording(db, patient, recording, device_id, blocks)
    except InvalidArgument as exc:
        name = file.filename if file is not None else "files"
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{name or 'file'}: {exc}") from None
    db.commit()
    return session


@router.get("/sessions/{session_id}/recording.csv", response_class=Response,
            responses={200: {"content": {"text/csv": {}}}})
async def export_recording(session_id: Id, therapist: Therapist, request: Request,
                           svc: Annotated[Services, Depends(get_services)]) -> Response:
    """The session's raw data as a recording file; it reads back to the stored numbers."""
    return await in_export_turn(request, therapist, _recording_file, session_id,
                                svc.settings.data_dir)


def _recording_file(db: DbSession, therapist: models.Therapist, session_id: int,
                    data_dir: Path) -> Response:
    session = own_session(db, therapist, session_id)
    recording = session_recording(db, session)
    if not recording.sensors:  # a recording file needs samples (was a 500)
        raise HTTPException(status.HTTP_409_CONFLICT, f"session {session_id} has no samples")
    return spooled(lambda out: write_recording_to(recording, out), data_dir, "text/csv",
                   f"session-{session_id}.csv")


@router.get("/sessions/{session_id}/angles.csv", response_class=Response,
            responses={200: {"content": {"text/csv": {}}}})
async def export_angles(session_id: Id, therapist: Therapist, request: Request,
                        svc: Annotated[Services, Depends(get_services)]) -> Response:
    """Per-sample joint angles [deg] and positions [m], as ``armtrack estimate`` writes."""
    return await in_export_turn(request, therapist, _angles_file, session_id, svc.settings.data_dir)


def _angles_file(db: DbSession, therapist: models.Therapist, session_id: int,
                 data_dir: Path) -> Response:
    session = own_session(db, therapist, session_id)
    columns, values = stored_estimates(db, session)
    if not columns:
        raise HTTPException(status.HTTP_409_CONFLICT, no_estimates_words(session))
    width = columns.index(ANGLE_COLUMNS_END) + 1
    return spooled(as_text(lambda out: write_angles_csv(out, columns[:width],
                                                        values[:, :width])),
                   data_dir, "text/csv", f"session-{session_id}-angles.csv")
