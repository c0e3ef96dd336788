"""Vendor files through the API (docs/extensions/recordings-upload.md): look inside
uploaded files before importing (which sensors, rates, durations, a calibration proposal,
side/height mismatches), import several files with a sensor map as a new session, and
follow its processing.

``POST /api/recordings`` (in :mod:`.sessions`) takes the vendor files; this module holds
the work it delegates and the routes of its own:

* ``POST /api/recordings/inspect``: multipart ``files`` (+ ``patient_id`` with a
  therapist's token) → what each file holds;
* ``GET /api/recordings/{session_id}/progress``: ``{"state": "processing"|"done"|"failed",
  ...}`` of an uploaded session.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from typing import Annotated

from armtrack.estimator.body import SENSOR_NAMES
from armtrack.estimator.errors import EstimatorError
from armtrack.estimator.importers import (
    Assignment,
    ImportFailure,
    ReadOptions,
    TooLarge,
    describe,
    detect,
    import_recording,
    read_signals,
)
from armtrack.estimator.importers.poses import propose_calibration
from armtrack.estimator.importers.sources import expand_upload
from armtrack.estimator.orientation import DEFAULT_FILTER
from armtrack.estimator.recording import Recording, SensorStream, parse_recording
from armtrack.estimator.recording.mismatch import body_mismatch, recording_mismatch
from fastapi import APIRouter, Depends, Form, HTTPException, UploadFile, status
from pydantic import BaseModel

from .. import audit
from ..db import models
from ..live.access import holds
from ..services import Services
from .deps import AtOnce, Db, own_patient
from .deps import services as get_services
from .schemas import MAX_ID, Id
from .sessions import uploader

router = APIRouter(prefix="/api/recordings", tags=["sessions"], responses={
    401: {"description": "not signed in, or not a kit's valid token"},
    404: {"description": "no such patient or uploaded session of this caller's"},
    413: {"description": "the files, or what a zip unpacks to, are over the upload limit"}})

#: Files one request may carry.
MAX_FILES = 64
RECORDING_MAGIC = b"# armtrack-recording"

#: Processing jobs of this process by session id (a session uploaded before a restart is
#: resubmitted by its progress route).
_jobs: dict[int, Future] = {}
_jobs_lock = threading.Lock()


class FoundSensor(BaseModel):
    format: str
    label: str
    files: list[str]
    rate_hz: float
    duration_s: float
    samples: int
    axes: int
    clock: str
    start: float | None
    notes: list[str]
    suggested: str | None
    #: the uploaded files this sensor's data comes from (zip members: the zip)
    uploads: list[str] = []
    #: True when those files hold other sensors too: name it as ``FILE:LABEL``
    label_needed: bool = False


class InspectedFile(BaseModel):
    name: str
    format: str | None
    sensors: list[FoundSensor]
    error: str | None = None
    side: str | None = None
    height_m: float | None = None
    mismatch: list[str] = []


class Inspection(BaseModel):
    files: list[InspectedFile]
    #: still periods that look like the poses (calibration value), from the suggested map
    proposal: str | None
    patient_side: str
    patient_height_m: float


class Progress(BaseModel):
    session_id: int
    state: str
    processed: bool
    error: str | None
    samples: int


def suggest(label: str, file_name: str) -> str | None:
    """The sensor a label or file name suggests (``Right Upper Arm`` → upper_arm)."""
    text = f"{label} {file_name}".lower().replace("-", " ").replace("_", " ")
    for sensor, words in (("upper_arm", ("upper arm", "upperarm", "humerus", "bicep")),
                          ("forearm", ("forearm", "fore arm", "lower arm")),
                          ("hand", ("hand", "wrist")),
                          ("clavicle", ("clavicle", "shoulder")),
                          ("trunk", ("trunk", "sternum", "chest", "thorax"))):
        if any(w in text for w in words):
            return sensor
    return None


def uploaded(files: list[UploadFile], limit: int) -> list:
    """The uploaded files, zips unpacked; all of them together at most ``limit`` bytes
    unpacked (the upload limit: a zip may not grow past what an upload may be)."""
    if len(files) > MAX_FILES:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"at most {MAX_FILES} files in one upload, got {len(files)}")
    out, total = [], 0
    for f in files:
        name = (f.filename or "file").replace("\\", "/").rsplit("/", 1)[-1]
        try:
            sources = expand_upload(name, f.file.read(), max(limit - total, 0))
        except TooLarge as exc:
            raise too_large(exc) from None
        except ImportFailure as exc:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
        total += sum(len(s.data) for s in sources)
        if total > limit:
            raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                                f"{name}: the files unpack to more than {limit} bytes "
                                "(ARMTRACK_MAX_UPLOAD_BYTES)")
        out.extend(sources)
    return out


def too_large(exc: TooLarge) -> HTTPException:
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, str(exc))


def patient_for(db, who, patient_id: int | None) -> models.Patient:
    if isinstance(who, models.Device):
        if patient_id is not None and patient_id != who.patient_id:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no patient {patient_id}")
        patient = db.get(models.Patient, who.patient_id)
        assert patient is not None
        return patient
    if patient_id is None:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "patient_id is required with a therapist's token")
    return own_patient(db, who, patient_id)


@router.post("/inspect", response_model=Inspection)
def inspect_files(db: Db, who: Annotated[models.Therapist | models.Device, Depends(uploader)],
                  svc: Annotated[Services, Depends(get_services)],
                  files: list[UploadFile],
                  patient_id: Annotated[int | None, Form(ge=1, le=MAX_ID)] = None,
                  options: Annotated[str | None, Form(max_length=2000)] = None) -> Inspection:
    """What each uploaded file holds: its format, the sensors in it (label, rate,
    duration, a suggested segment), side/height mismatches of armtrack recordings with the
    patient's record, and a calibration proposal. Nothing is stored. A kit's token has
    its files read one request at a time: another arriving meanwhile is answered 429 at
    once."""
    patient = patient_for(db, who, patient_id)
    with _kit_turn(who):
        return _inspect(patient, files, _options(options, svc.settings.max_upload_bytes),
                        svc.settings.max_upload_bytes)


#: Kits whose files this process is reading for an inspection (device ids).
_inspecting: set[int] = set()
_inspecting_lock = threading.Lock()
INSPECT_BUSY = ("another inspection from this kit is being read; send this one when it is "
                "done")


#: A therapist's uploads and inspections read at once, all their sign-ins together (two
#: tabs); each reads its files whole into memory on a worker thread.
THERAPIST_READS_AT_ONCE = 2
#: Therapists' uploads and inspections being read now.
_therapist_reads = AtOnce(THERAPIST_READS_AT_ONCE)
THERAPIST_BUSY = (f"this account has {THERAPIST_READS_AT_ONCE} uploads or inspections being "
                  "read at once, the most it may: send this one when one is done")


@contextlib.contextmanager
def therapist_turn(therapist: models.Therapist) -> Iterator[None]:
    """At most ``THERAPIST_READS_AT_ONCE`` uploads and inspections of one therapist read at
    once; the next is refused (429, ``THERAPIST_BUSY``) rather than read too. A kit's had
    their bound, a therapist's none: 12 inspections of a 30 MB recording at once from one
    therapist took the server +770 MB and another therapist's page to 2.2 s, 12 uploads
    +502 MB (at the 200 MB upload limit and 40 worker threads: tens of GB)."""
    with _therapist_reads.turn(therapist.id, THERAPIST_BUSY):
        yield


@contextlib.contextmanager
def _kit_turn(who: models.Therapist | models.Device) -> Iterator[None]:
    """One inspection at a time per kit token: each reads its files whole into memory on
    a worker thread (12 at once from one kit took the server from 0.57 to 1.19 GB and
    another therapist's request to 1.4 s), so one arriving while another of the kit is
    read is refused (429, ``INSPECT_BUSY``) rather than read too; a therapist's go by
    ``therapist_turn``."""
    if not isinstance(who, models.Device):
        with therapist_turn(who):
            yield
        return
    with _inspecting_lock:
        if who.id in _inspecting:
            raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, INSPECT_BUSY)
        _inspecting.add(who.id)
    try:
        yield
    finally:
        with _inspecting_lock:
            _inspecting.discard(who.id)


def _inspect(patient: models.Patient, files: list[UploadFile], read_options: ReadOptions,
             limit: int) -> Inspection:
    out, suggested = [], {}
    groups: dict[str, list] = {}
    for source in uploaded(files, limit):
        top = source.name.split("/", 1)[0]
        groups.setdefault(top, []).append(source)
    # formats of one file per signal (MetaMotion, loose Sensor Logger files) are read
    # together, so their files meet; the others file by file (or zip by zip)
    pooled: dict[str, list] = {}
    readable: list[tuple[str, str, list]] = []
    for name, sources in groups.items():
        if len(sources) == 1 and sources[0].data.lstrip()[:20] == RECORDING_MAGIC:
            out.append(_inspect_recording(name, sources[0].data, patient))
            continue
        try:
            fmt = detect(sources)
        except EstimatorError as exc:
            out.append(InspectedFile(name=name, format=None, sensors=[], error=str(exc)))
            continue
        if fmt in ("metamotion", "sensor-logger") and len(sources) == 1:
            pooled.setdefault(fmt, []).extend(sources)
        else:
            readable.append((name, fmt, sources))
    readable += [(", ".join(s.name for s in sources), fmt, sources)
                 for fmt, sources in pooled.items()]
    for name, fmt, sources in readable:
        try:
            found = read_signals(sources, fmt, read_options)
        except TooLarge as exc:
            raise too_large(exc) from None
        except EstimatorError as exc:
            out.append(InspectedFile(name=name, format=fmt, sensors=[], error=str(exc)))
            continue
        sensors = []
        for signal in found:
            guess = suggest(signal.label, name)
            if guess in suggested:
                guess = None
            if guess:
                suggested[guess] = signal
            uploads = list(dict.fromkeys(f.split(":/", 1)[0].split("/", 1)[0]
                                         for f in signal.files))
            sensors.append(FoundSensor(**describe(signal), suggested=guess, uploads=uploads,
                                       label_needed=len(found) > 1))
        out.append(InspectedFile(name=name, format=fmt, sensors=sensors))
    proposal = None
    clocks = {s.clock for s in suggested.values()}
    if suggested and len(clocks) == 1:
        t0 = min(s.epoch + float(s.t[0]) for s in suggested.values())
        streams = {k: SensorStream(t=(s.epoch - t0) + s.t, acc=s.acc, gyr=s.gyr)
                   for k, s in suggested.items()}
        proposal = propose_calibration(streams)
    return Inspection(files=out, proposal=proposal, patient_side=patient.side,
                      patient_height_m=patient.height_m)


def _inspect_recording(name: str, data: bytes, patient) -> InspectedFile:
    try:
        recording = parse_recording(data)
    except EstimatorError as exc:
        return InspectedFile(name=name, format="armtrack", sensors=[], error=f"{name}: {exc}")
    sensors = [FoundSensor(format="armtrack", label=n, files=[name],
                           rate_hz=round(_rate(s), 2), duration_s=round(float(s.t[-1] - s.t[0]), 2),
                           samples=len(s), axes=9 if s.mag is not None else 6, clock="file",
                           start=float(s.t[0]), notes=[], suggested=n)
               for n, s in recording.sensors.items()]
    return InspectedFile(name=name, format="armtrack", sensors=sensors, side=recording.side,
                         height_m=recording.height_m,
                         mismatch=recording_mismatch(recording, patient.side, patient.height_m))


def _rate(stream) -> float:
    import numpy as np

    dt = np.diff(stream.t)
    dt = dt[dt > 0]
    return float(1 / np.median(dt)) if dt.size else 0.0


def _options(text: str | None, limit: int) -> ReadOptions:
    """The ``options`` form field; ``limit``: what the files' data may decode to [bytes]."""
    if not text:
        return ReadOptions(max_bytes=limit)

    def bad(problem: str) -> HTTPException:
        return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                             f"options must be JSON {{field_ut, columns, platform}}: {problem}")

    try:
        raw = json.loads(text)
    except (ValueError, RecursionError) as exc:  # nesting past the limit: RecursionError
        raise bad(f"not JSON ({exc})") from None
    if not isinstance(raw, dict):
        raise bad("not a JSON object")
    field_ut = raw.get("field_ut", 50.0)
    if isinstance(field_ut, bool) or not isinstance(field_ut, int | float) \
            or not 0 < field_ut < 1e4:
        raise bad(f"field_ut must be a field strength in µT, got {field_ut!r}")
    for key in ("columns", "platform"):
        if raw.get(key) is not None and not isinstance(raw[key], str):
            raise bad(f"{key} must be text, got {raw[key]!r}")
    return ReadOptions(field_ut=float(field_ut), columns=raw.get("columns"),
                       platform=raw.get("platform"), max_bytes=limit)


def assignments(sources: list, sensor_map: str, fmt: str | None) -> list[Assignment]:
    """The ``sensors`` form field (JSON: ``{"upper_arm": "a.csv", "forearm":
    "session.h5:Right Forearm", "hand": ["acc.csv", "gyro.csv"]}``; a zip or folder name
    stands for all its files) → assignments of the uploaded files."""
    try:
        mapping = json.loads(sensor_map)
        assert isinstance(mapping, dict)
    except (ValueError, AssertionError, RecursionError):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            'sensors must be a JSON object like {"forearm": "dot2.csv"}') from None
    out = []
    for sensor, value in mapping.items():
        if sensor not in SENSOR_NAMES:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"sensors: unknown sensor {sensor!r} (one of "
                                f"{', '.join(SENSOR_NAMES)})")
        names = value if isinstance(value, list) else [value]
        chosen, label = [], None
        for item in names:
            if not isinstance(item, str) or not item:
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                    f"sensors: {sensor} must name uploaded files")
            name, _, tail = item.partition(":")
            if tail:
                label = tail
            match = [s for s in sources if s.name == name or s.name.startswith(name + "/")]
            if not match:
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                    f"sensors: {sensor}: no uploaded file {name!r}")
            chosen.extend(match)
        out.append(Assignment(sensor, chosen, label, fmt))
    if not out:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "sensors names no sensor")
    return out


def import_upload(files: list[UploadFile], sensor_map: str, patient: models.Patient,
                  fmt: str | None, calibration: str | None, side: str | None,
                  height_m: float | None, options: str | None, limit: int) -> Recording:
    """The recording of vendor files (refused whole, naming file, line and problem)."""
    sources = uploaded(files, limit)
    chosen = assignments(sources, sensor_map, fmt)
    problems = body_mismatch(patient.side, patient.height_m, side, height_m)
    if problems:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            "side/height differ from the patient's record: " + "; ".join(problems))
    try:
        result = import_recording(chosen, side=side or patient.side,
                                  height_m=height_m or patient.height_m,
                                  calibration=calibration or None,
                                  options=_options(options, limit))
    except TooLarge as exc:
        raise too_large(exc) from None
    except ImportFailure as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    return result.recording


def start_processing(svc: Services, session_id: int) -> Future:
    with _jobs_lock:
        job = _jobs.get(session_id)
        if job is None or job.done():
            job = svc.processing.submit(session_id, DEFAULT_FILTER)
            _jobs[session_id] = job
            job.add_done_callback(lambda _f: _forget(session_id))
        return job


def _forget(session_id: int) -> None:
    with _jobs_lock:
        job = _jobs.get(session_id)
        if job is not None and job.done():
            del _jobs[session_id]


@router.get("/{session_id}/progress", response_model=Progress)
def progress(session_id: Id, db: Db,
             who: Annotated[models.Therapist | models.Device, Depends(uploader)],
             svc: Annotated[Services, Depends(get_services)]) -> Progress:
    """Where an uploaded session's processing is: ``processing`` (resubmitted when this
    server no longer works on it, e.g. after a restart), ``done`` or ``failed``."""
    session = db.get(models.Session, session_id)
    if session is None or session.source != "upload":
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no uploaded session {session_id}")
    if isinstance(who, models.Device):
        if session.patient_id != who.patient_id:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no uploaded session {session_id}")
    else:
        patient = db.get(models.Patient, session.patient_id)
        if not holds(who, patient):  # as if it did not exist (an admin holds no patient)
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no uploaded session {session_id}")
    audit.note(patient_id=session.patient_id, session_id=session.id)
    if session.estimate_columns:
        state = "done"
    elif session.processing_error:
        state = "failed"
    else:
        state = "processing"
        with _jobs_lock:
            running = session_id in _jobs
        if not running:
            start_processing(svc, session_id)
    return Progress(session_id=session.id, state=state, processed=state == "done",
                    error=session.processing_error, samples=session.samples)
