"""``/ws/ingest``: one kit's connection (``docs/spec/ingest.md``). Authenticates the device,
takes ``hello``, starts or resumes the stream's session, then takes messages strictly in
``seq`` order: accepted ones go to the group writer (acked once stored) and to the live
worker; refused ones get an ``error`` naming their ``seq``.

Extension, a new stream in the same session (the spec is silent on it): a kit whose clock
jumped backwards gets its samples refused (``t goes backwards … starts a new stream in
this session``); it cannot resume its stream, whose times must go on. It says ``hello``
with ``"resume": null`` and ``"session": <id>`` (the session of its ``ready``), with the
same side and sensors. The server closes any connection still open on that session, and
answers ``ready`` with a new ``stream``, the same ``session``, ``next_seq`` 0 and
``"t_offset": <s>``: the new stream's times are stored shifted by ``t_offset`` (a float64
addition), so that its clock's 0 falls one sample period after the session's last stored
time (sample or mark); marks too. A restarted clock thus continues the session; a clock
that did not restart leaves a gap, reported in the session's data quality. The new
stream's blocks are ordered after the session's earlier ones; the earlier streams can no
longer be resumed (their clock is behind). A closed session cannot be continued.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections import deque
from datetime import datetime
from typing import Any

from armtrack.estimator.arm.coverage import coverage, measured_angles
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.errors import EstimatorError
from armtrack.estimator.orientation import DEFAULT_FILTER
from armtrack.estimator.pipeline import PipelineConfig
from fastapi import APIRouter, WebSocket
from sqlalchemy import func, select, update
from sqlalchemy.orm import Session as DbSession
from starlette.websockets import WebSocketDisconnect, WebSocketState

from .. import clock
from ..auth import hash_token
from ..db import models
from ..kit import daily_samples, discharge, new_sessions
from ..live.worker import LiveWorker
from ..programs import stream as program_stream
from ..programs.today import exercise_bands
from ..services import Services
from ..store.gyro_bias import session_prior, session_priors_by_id
from ..store.processing import mark_closed
from ..store.stopped import record_stop
from . import budget, carried_on, protocol
from .feedback import FEEDBACK_EXTENSION, Band, FeedbackRunner, FeedbackTracker
from .protocol import Hello, Refused
from .writer import (
    HEARD_KEY,
    MAX_PENDING_PER_STREAM,
    ORDINAL_BASE_KEY,
    T_OFFSET_KEY,
    StreamState,
    Write,
)

log = logging.getLogger("armtrack.ingest")
router = APIRouter()

#: Extension (docs/extensions/README.md): the ``error`` refusing the resume of a closed
#: session's stream carries ``next_seq``, what of the stream is stored.
CLOSED_SESSION_EXTENSION = "closed-session/1"

#: Least time between two acks of a streaming kit [s] (the spec asks for one a second).
ACK_EVERY_S = 0.25
#: Most marks a session keeps (a session of a dozen exercises has a few dozen): past
#: that a mark is refused naming the limit, nothing stored, the connection open.
MARKS_PER_SESSION_MAX = 1000


def find_device(db: DbSession, token: str | None) -> tuple[int, int, int | None] | None:
    """(device id, patient id, the patient's therapist's id) of a valid, unrevoked device
    token."""
    if not token:
        return None
    found = db.execute(select(models.Device.id, models.Device.patient_id,
                              models.Patient.therapist_id)
                       .join(models.Patient, models.Patient.id == models.Device.patient_id)
                       .where(models.Device.token_hash == hash_token(token),
                              models.Device.revoked_at.is_(None))).first()
    return None if found is None else tuple(found)


def bearer(websocket: WebSocket) -> str | None:
    header = websocket.headers.get("authorization", "")
    scheme, _, value = header.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return websocket.query_params.get("token")


@router.websocket("/ws/ingest")
async def ingest(websocket: WebSocket) -> None:
    services: Services = websocket.app.state.services
    found = await services.run_db(find_device, bearer(websocket))
    await websocket.accept()
    if found is None:
        await websocket.close(protocol.CLOSE_BAD_TOKEN, "bad or revoked device token")
        return
    device_id = found[0]
    limit = services.settings.max_streams_per_kit
    if services.kit_sockets.get(device_id, 0) >= limit:  # one token, no flood of sessions
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
            await websocket.send_text(protocol.dumps({
                "type": "error", "seq": None,
                "reason": f"this kit has {limit} streams open already, the most one kit may "
                          "hold (ARMTRACK_MAX_STREAMS_PER_KIT): end one first"}))
            await websocket.close(protocol.CLOSE_TOO_MANY_ERRORS, "too many streams open")
        return
    services.kit_sockets[device_id] = services.kit_sockets.get(device_id, 0) + 1
    try:
        connection = IngestConnection(services, websocket, *found)
        await connection.run()
    finally:
        if (left := services.kit_sockets[device_id] - 1) > 0:
            services.kit_sockets[device_id] = left
        else:
            del services.kit_sockets[device_id]
            if services.kit_budgets[device_id].full():  # else kept: a reconnect pays on
                del services.kit_budgets[device_id]
            services.kit_samples.pop(device_id, None)  # counted again at its next stream


class IngestConnection:
    def __init__(self, services: Services, websocket: WebSocket, device_id: int,
                 patient_id: int, therapist_id: int | None = None):
        self.services = services
        self.settings = services.settings
        self.websocket = websocket
        self.device_id = device_id
        self.patient_id = patient_id
        self.therapist_id = therapist_id
        self.hello: Hello | None = None
        self.state: StreamState | None = None
        self.worker: LiveWorker | None = None
        self._refused: deque[float] = deque()
        self._ack_wanted = asyncio.Event()
        self._acked = -1
        self._closed = False
        self._send_lock = asyncio.Lock()
        self.ended = asyncio.Event()  # set once _end is through
        self.received = 0
        self.sensor_stats: dict[str, dict[str, Any]] = {}
        self.feedback: FeedbackRunner | None = None
        #: marks the session holds (counted from the database at this stream's first)
        self.marks_kept: int | None = None
        #: samples the session holds (counted from the database at this stream's first)
        self.samples_kept: int | None = None
        #: when this stream's session was created (its kit's day counts its rows by it)
        self.session_created_at: datetime | None = None
        #: the first message refused because the session is full (ARMTRACK_MAX_SESSION_SAMPLES)
        self._full_from: int | None = None
        #: programs/1 (docs/extensions/programs-hello.md): the program hello named, and
        #: what ready says of it
        self.program_ref: int | str | None = None
        #: carried-on/1 (docs/extensions/carried-on.md): the kit's session this one carries on
        self.carries_on: int | None = None
        self.program: dict[str, Any] | None = None
        self.program_error: str | None = None
        #: the server stopped this stream after ready (store/stopped.py's record)
        self.stopped: dict[str, Any] | None = None
        #: how fast this kit's messages are read, all its streams together
        self.budget = services.kit_budget(device_id)
        self._slice_from = time.perf_counter()

    # -- sending ------------------------------------------------------------------------
    async def send(self, message: dict[str, Any]) -> None:
        if self._closed:
            return
        text = protocol.dumps(message)  # outside the suppress: a message it cannot encode
        async with self._send_lock:  # is a bug to see, not a vanished peer
            # a vanished peer (Starlette's WebSocketDisconnect for the transport's OSError,
            # its RuntimeError once the socket is closed) ends in receive(); anything else
            # is a bug, and raises
            with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                await self.websocket.send_text(text)

    async def close(self, code: int, reason: str) -> None:
        if self._closed:
            return
        self._closed = True
        if self.websocket.application_state != WebSocketState.DISCONNECTED:
            with contextlib.suppress(Exception):
                await self.websocket.close(code, protocol.close_reason(reason, code))

    async def _ack_loop(self) -> None:
        """Acks what is stored (the group writer's ``on_durable`` wakes it after each
        commit that holds this stream's messages), and a duplicate again. While the kit
        streams, at most one ack every ``ACK_EVERY_S``: each ack is a frame and a system
        call, and a kit keeps its unacked messages anyway. A commit that leaves nothing
        of the stream pending is acked at once, so the last messages before a pause are
        never left unacked. No timer: ``asyncio.wait_for`` made a task per wake-up."""
        assert self.state is not None
        state = self.state
        acked_at = -float("inf")
        while not self._closed:
            await self._ack_wanted.wait()
            self._ack_wanted.clear()
            durable = state.durable_seq
            if durable >= 0 and (durable > self._acked or self._resend_ack):
                now = time.monotonic()
                if state.pending and not self._resend_ack and now - acked_at < ACK_EVERY_S:
                    continue  # more is on its way: its commit wakes this loop again
                acked_at = now
                self._resend_ack = False
                self._acked = durable
                await self.send({"type": "ack", "seq": durable})

    _resend_ack = False
    _said_bye = False

    async def refuse(self, error: Refused) -> None:
        # always the spec's shape: ``seq`` is null when the message had none to name
        await self.send({"type": "error", "seq": error.seq, "reason": error.reason,
                         **error.extra})
        if error.close_code is not None:
            await self.close(error.close_code, error.reason)  # whole, or the short form
            return
        if not error.counted:
            return
        now = time.monotonic()
        self._refused.append(now)
        while self._refused and self._refused[0] < now - self.settings.refused_window_s:
            self._refused.popleft()
        if len(self._refused) > self.settings.refused_limit:
            reason = (f"more than {self.settings.refused_limit} refused messages in "
                      f"{self.settings.refused_window_s:g} s")
            # kept on the session for the therapist (docs/extensions/stream-stopped.md):
            # the phone kit stops for good after it and asks its patient to call them
            self.stopped = {"at": clock.now().isoformat(),
                            "close_code": protocol.CLOSE_TOO_MANY_ERRORS, "reason": reason,
                            "refused": len(self._refused),
                            "refused_limit": self.settings.refused_limit,
                            "window_s": float(self.settings.refused_window_s),
                            "last_refused": error.reason}
            await self.close(protocol.CLOSE_TOO_MANY_ERRORS, reason)

    # -- the connection -----------------------------------------------------------------
    async def receive(self) -> str | None:
        """The next text (or binary, as UTF-8 JSON) message; None when the peer is gone."""
        message = await self.websocket.receive()
        if message["type"] == "websocket.disconnect":
            return None
        data = message.get("text")
        if data is None:
            data = message.get("bytes") or b""
        if len(data) > self.settings.max_message_bytes:
            await self.send({"type": "error", "seq": None,
                             "reason": f"message of {len(data)} bytes is over "
                             f"the limit of {self.settings.max_message_bytes}"})
            await self.close(protocol.CLOSE_TOO_BIG, "message too big")
            return None
        return data

    async def run(self) -> None:
        ack_task = None
        try:
            if not await self._start():
                return
            ack_task = asyncio.create_task(self._ack_loop())
            while not self._closed:
                await self._pace()
                text = await self.receive()
                if text is None:
                    break
                self.budget.spend(messages=1)
                if not await self._handle(text):
                    break
        except WebSocketDisconnect:
            pass
        finally:
            try:
                await self._end(ack_task)
            finally:
                self.ended.set()

    async def _pace(self) -> None:
        """Before the next message: wait while the kit is past its budget (its socket
        unread: back-pressure), then for its turn in all kits' budget, and let the loop
        serve others after ``SLICE_S`` of messages handled back to back (one read may
        bring in hundreds)."""
        paused = False
        if (wait := self.budget.wait_s()) >= budget.PAUSE_MIN_S:
            await asyncio.sleep(wait)
            paused = True
        if (wait := self.services.ingest_budget.turn_s(self.therapist_id)) >= budget.PAUSE_MIN_S:
            await asyncio.sleep(wait)  # its therapist's kits' turns, in the order taken
        elif not paused and time.perf_counter() - self._slice_from < budget.SLICE_S:
            return
        elif not paused:
            await asyncio.sleep(0)
        self._slice_from = time.perf_counter()

    def _spend_rows(self, rows: int) -> None:
        """Count ``rows`` sample rows read, in the kit's budget and all kits'."""
        self.budget.spend(rows=rows)
        self.services.ingest_budget.spend(self.therapist_id, rows=rows)

    async def _start(self) -> bool:
        text = await self.receive()
        if text is None:
            return False
        try:
            message = protocol.parse(text)
            self.hello = protocol.check_hello(message)
            self.program_ref = program_stream.check_program(message, self.hello)
            self.carries_on = carried_on.check(message, self.hello)
            ready = await self._open_stream(self.hello)
        except Refused as error:
            if error.close_code is None:
                error.close_code = protocol.CLOSE_BAD_PROTOCOL
            await self.refuse(error)
            return False
        await self.send(ready)
        return True

    async def _open_stream(self, hello: Hello) -> dict[str, Any]:
        services = self.services
        extra: dict[str, Any] = {}
        # the token was read at the connection, which a revoke does not see until its hello
        # has made a stream: read again now (a revoke from here on closes the stream)
        await services.run_db(self._check_kit)
        if hello.resume is not None or hello.session is not None:
            # another patient's session or stream is refused before anything is touched:
            # no connection of theirs closed, nothing waited for
            await services.run_db(self._check_own, hello)
        if hello.resume is None and hello.session is not None:
            # a new stream in the session: any connection still open on it ends first
            for old in list(services.connections.values()):
                if old.state is not None and old.state.session_id == hello.session:
                    await old.close(1001, "replaced by a new stream of its session")
                    await old.ended.wait()
            stream_id = secrets.token_hex(12)
            session_id, height, last_t = await services.run_db(
                self._continue_session, hello, stream_id)
            state = StreamState(stream_id, session_id, 0, last_t)
            extra["t_offset"] = state.t_offset
        elif hello.resume is None:
            stream_id = secrets.token_hex(12)
            session_id, height = await services.run_db(self._create_session, hello, stream_id)
            state = StreamState(stream_id, session_id, 0, {})
        else:
            stream_id = hello.resume
            old = services.connections.get(stream_id)
            if old is not None:  # the kit reconnected before the old socket timed out
                await old.close(1001, "replaced by a resumed connection")
                # its end (which marks the session interrupted) must not follow the resume
                await old.ended.wait()
            state = services.streams.get(stream_id)
            if state is not None:
                await state.idle.wait()  # everything accepted before is stored first
            found = await services.run_db(self._resume_session, hello, stream_id)
            session_id, height, next_seq, last_t = found
            if state is None:
                state = StreamState(stream_id, session_id, next_seq, last_t)
            else:
                state.next_seq = state.durable_seq + 1
                state.last_t = dict(state.stored_last_t)
        state.on_durable = self._ack_wanted.set
        state.on_storage_error = self._storage_error
        state.on_fenced = self._fenced
        services.streams[stream_id] = state
        services.connections[stream_id] = self
        self.state = state
        # a resumed stream whose lost connection left its live side here goes on with it:
        # calibrated, its repetitions counting on (Services.park_live)
        parked = services.take_live(stream_id) if hello.resume is not None else None
        if parked is not None:
            self.worker = parked.worker
        else:
            # the kit's remembered gyroscope biases, as the session keeps them
            priors = await services.run_db(session_priors_by_id, session_id)
            delay = await services.run_db(_session_delay, session_id)
            try:
                config = PipelineConfig(side=hello.side,
                                        lengths=SegmentLengths.from_height(height),
                                        sensors=hello.sensors, gyro_delay_s=delay)
                self.worker = LiveWorker(
                    config, patient_id=self.patient_id, session_id=session_id,
                    hub=services.hub, batcher=services.live,
                    max_rate_hz=self.settings.live_poses_hz,
                    points_frame=hello.points.frame if hello.points else None,
                    gyr_bias_priors=priors,
                    clinic_timezone=self.settings.clinic_timezone)
            except EstimatorError as exc:  # the data are still stored; only live view is off
                log.warning("no live estimates for session %s: %s", session_id, exc)
        if hello.extensions:  # docs/extensions/README.md: those this server speaks
            extra["extensions"] = [e for e in hello.extensions
                                   if e in (FEEDBACK_EXTENSION, CLOSED_SESSION_EXTENSION,
                                            carried_on.EXTENSION)
                                   or e in program_stream.SPOKEN]
        if FEEDBACK_EXTENSION in hello.extensions:
            if parked is not None and parked.feedback is not None:
                self.feedback = parked.feedback
                self.feedback.send = self.send
            else:
                bands, marks = await services.run_db(_feedback_start, self.patient_id,
                                                     session_id)
                tracker = FeedbackTracker({k: Band(*v) for k, v in bands.items()},
                                          measured_angles(hello.sensors),
                                          SegmentLengths.from_height(height))
                for t, label in marks:  # a resumed stream: the exercise under way goes on
                    tracker.mark(t, label, stored=True)
                self.feedback = FeedbackRunner(tracker, services.run_cpu, self.send)
            if self.worker is not None:
                self.worker.on_pose = self.feedback.pose
        if program_stream.PROGRAMS_EXTENSION in hello.extensions:
            extra["program"] = self.program
            if self.program_error:
                extra["program_error"] = self.program_error
        services.hub.publish(self.patient_id, {"kind": "session", "session_id": session_id,
                                               "status": "live"})
        return {"type": "ready", "stream": stream_id, "session": session_id,
                "next_seq": state.next_seq, **extra}

    def _check_own(self, db: DbSession, hello: Hello) -> None:
        """Refuse a ``hello`` naming a session or stream that is not this device's
        patient's, with the same words as one that does not exist, or one whose kit differs
        from the session's (side, sensors, gyroscope delay): before any connection of the
        session is closed for it, so a refused hello leaves the running stream alone."""
        if hello.resume is not None:
            stream = db.get(models.Stream, hello.resume)
            session = None if stream is None else db.get(models.Session, stream.session_id)
            if session is None or session.patient_id != self.patient_id:
                raise Refused(f"hello: no stream {hello.resume!r} to resume for this "
                              "device's patient")
            if not self._ends_anyway(session) and "~continued_by" not in (stream.last_t or {}):
                _same_kit(hello, session, "a resumed stream")
        elif hello.session is not None:
            session = db.get(models.Session, hello.session)
            if session is None or session.patient_id != self.patient_id:
                raise Refused(f"hello: no session {hello.session} to continue for this "
                              "device's patient")
            if not self._ends_anyway(session):
                _same_kit(hello, session, "a stream continuing a session")

    def _ends_anyway(self, session: models.Session) -> bool:
        """A closed (or closing) session: the store step refuses its hello with its own
        words (closed-session/1's ``next_seq``), before any other check."""
        return session.status == "closed" or session.id in self.services.closing

    def _check_kit(self, db: DbSession) -> None:
        """Refuse the hello (4401) of a kit revoked, or erased with its patient, since its
        socket connected. Before, a socket opened ahead and kept idle started a session
        after the revoke and streamed into it, acked, until the periodic check
        (tests/test_security_ingest.py); with the patient erased, the hello failed on an
        assertion."""
        device = db.get(models.Device, self.device_id)
        if device is None or device.revoked_at is not None:
            raise Refused("hello: this kit's token was revoked, or its patient erased, since "
                          "it connected: ask the therapist for a new kit link",
                          close_code=protocol.CLOSE_BAD_TOKEN)

    def _create_session(self, db: DbSession, hello: Hello, stream_id: str) -> tuple[int, float]:
        patient = db.get(models.Patient, self.patient_id)
        assert patient is not None
        if (why := discharge.refusal(patient)) is not None:  # before anything is stored
            raise Refused(f"hello: {why}")
        # one token, no flood of sessions (each one costs every later progress report):
        # refused before anything is stored; the kit keeps its data and tries again later.
        # Counted in the kit's turn, held until the commit below: an upload of the kit
        # racing this hello counts before or after it, never beside it
        if not new_sessions.count_turn(db, self.device_id, wait_s=new_sessions.HELLO_WAIT_S):
            raise Refused(f"hello: {new_sessions.BUSY_HELLO}",
                          close_code=protocol.CLOSE_TOO_MANY_ERRORS)  # before ready: waited on
        why = new_sessions.refusal(db, self.device_id,
                                   self.settings.max_new_sessions_per_kit_hour)
        if why is not None:
            raise Refused(f"hello: {why}", close_code=protocol.CLOSE_TOO_MANY_ERRORS)
        self._day_left(db)
        session = models.Session(
            patient_id=patient.id, device_id=self.device_id, source="stream", status="live",
            side=hello.side, height_m=patient.height_m, rate_hz=hello.rate_hz,
            sensors={s: {"nine_axis": hello.nine_axis} for s in hello.sensors},
            meta={"device": hello.device, **coverage(hello.sensors),
                  **(hello.points.as_meta() if hello.points else {})},
            started_at=(now := clock.now()), created_at=now,
            gyro_bias_prior=session_prior(db, self.device_id),
            gyro_delay_s=hello.gyro_delay_s)
        db.add(session)
        db.flush()
        db.add(models.Stream(id=stream_id, session_id=session.id, device_id=self.device_id,
                             next_seq=0, last_t={}))
        if self.carries_on is not None:
            carried_on.link(db, session, self.carries_on)
        if self.program_ref is not None:
            self.program, self.program_error = program_stream.follow_program(
                db, patient.id, session.id, self.program_ref)
        db.commit()
        return session.id, patient.height_m

    def _day_left(self, db: DbSession) -> None:
        """Refuse a new session or stream (close 4429, before anything is stored) when the
        kit's day is spent (``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY``): it would be let in only
        to have every message refused. Counted from the database, or by this instance's
        streams when they are ahead (rows in flight)."""
        counted = self.services.kit_samples.get(self.device_id)
        kept = max(daily_samples.stored(db, self.device_id),
                   0 if counted is None else counted.total())
        if (why := daily_samples.spent(kept, self.settings.max_kit_samples_per_day)):
            raise Refused(f"hello: {why}", close_code=protocol.CLOSE_TOO_MANY_ERRORS)

    def _continue_session(self, db: DbSession, hello: Hello, stream_id: str
                          ) -> tuple[int, float, dict[str, Any]]:
        """A new stream in session ``hello.session`` (the extension above): its last
        sample time per sensor, clock offset and first block ordinal."""
        session = db.get(models.Session, hello.session)
        if session is None or session.patient_id != self.patient_id:
            raise Refused(f"hello: no session {hello.session} to continue for this device's "
                          "patient")
        if session.status == "closed" or session.id in self.services.closing:
            raise _continued_closed(session.id)
        _same_kit(hello, session, "a stream continuing a session")  # (checked again: a race)
        self._day_left(db)
        blocks = models.SampleBlock
        ends = dict(db.execute(
            select(blocks.sensor, func.max(blocks.t_last))
            .where(blocks.session_id == session.id).group_by(blocks.sensor)).all())
        top = db.scalar(select(func.max(blocks.ordinal)).where(blocks.session_id == session.id))
        last_mark = db.scalar(select(func.max(models.Mark.t))
                              .where(models.Mark.session_id == session.id))
        latest = [float(t) for t in [*ends.values(), last_mark] if t is not None]
        rate = hello.rate_hz or session.rate_hz or 100.0
        last_t: dict[str, Any] = {name: float(t) for name, t in ends.items()}
        last_t[T_OFFSET_KEY] = max(latest) + 1.0 / rate if latest else 0.0
        last_t[ORDINAL_BASE_KEY] = 0 if top is None else int(top) + 1
        for earlier in session.streams:  # their clock is behind: no resume any more
            earlier.last_t = {**earlier.last_t, "~continued_by": stream_id}
        db.add(models.Stream(id=stream_id, session_id=session.id, device_id=self.device_id,
                             next_seq=0, last_t=last_t))
        if not _reopened(db, session.id):  # closed on another instance since the check
            raise _continued_closed(session.id)
        self.program = program_stream.followed_program(db, session.id)
        return session.id, session.height_m, last_t

    def _resume_session(self, db: DbSession, hello: Hello, stream_id: str
                        ) -> tuple[int, float, int, dict[str, float]]:
        stream = db.get(models.Stream, stream_id)
        session = None if stream is None else db.get(models.Session, stream.session_id)
        if session is None or session.patient_id != self.patient_id:
            raise Refused(f"hello: no stream {stream_id!r} to resume for this device's patient")
        # what of it is stored: the kit sends the rest (closing: the therapist's close is
        # under way, its commit a moment away)
        if session.status == "closed" or session.id in self.services.closing:
            raise _resumed_closed(hello, stream_id, stream.next_seq)
        if "~continued_by" in (stream.last_t or {}):
            raise Refused(f"hello: session {session.id} goes on in a newer stream; "
                          f"continue it with resume null and session {session.id}")
        _same_kit(hello, session, "a resumed stream")
        next_seq = stream.next_seq
        if not _reopened(db, session.id):  # closed on another instance since the check
            raise _resumed_closed(hello, stream_id, next_seq)
        self.program = program_stream.followed_program(db, session.id)
        return session.id, session.height_m, stream.next_seq, dict(stream.last_t)

    async def _keep_stop(self, session_id: int) -> None:
        """The server stopped this stream: the session keeps why and when."""
        try:
            await self.services.run_db(record_stop, session_id, self.stopped)
        except Exception as exc:  # the database locked or full: the kit was told anyway
            log.warning("session %s: its stream's stop not kept: %s", session_id, exc)

    def _fenced(self, why: str) -> None:
        """Another instance stores this stream now, or its session was closed there
        (``writer``'s "Fencing"): this connection ends without marking the session
        interrupted; the kit resumes (and is told then if the session is closed)."""
        asyncio.get_running_loop().create_task(
            self.close(1000, "session closed by the therapist") if why == "closed"
            else self.close(1013, "the stream goes on on another server: resume"))

    def _storage_error(self, reason: str) -> None:
        error = {"type": "error", "seq": None, "reason": reason}
        asyncio.get_running_loop().create_task(self.send(error))

    async def _handle(self, text: str) -> bool:
        """One message after hello; False when the stream is over."""
        assert self.state is not None and self.hello is not None
        received = time.monotonic()
        state = self.state
        try:
            message = protocol.parse(text)
            kind = message["type"]
            if kind in ("samples", "mark", "points"):
                seq = protocol.check_seq(message)
                if seq < state.next_seq:  # a duplicate: dropped, acked again
                    self._resend_ack = True
                    self._ack_wanted.set()
                    return True
                if seq > state.next_seq:
                    raise Refused(f"seq {seq} is ahead: expected {state.next_seq}", seq)
                state.next_seq += 1
                try:
                    if self._full_from is not None:  # nothing more, in order (see _room_for)
                        raise Refused(f"{kind}: this session is full since message "
                                      f"{self._full_from} " + protocol.SESSION_FULL, seq,
                                      counted=False)
                    if kind == "samples":
                        item = protocol.check_samples(message, seq, self.hello, state.last_t,
                                                     state.t_offset)
                        self._spend_rows(len(item.rows))
                        await self._room_for(len(item.rows), seq)
                        state.last_t[item.sensor] = float(item.rows[-1, 0])
                        self.received += len(item.rows)
                        self._count(item.sensor, len(item.rows), received)
                        self.services.writer.submit(Write(state, seq, samples=item))
                    elif kind == "points":  # docs/extensions/points.md
                        item = protocol.check_points(message, seq, self.hello, state.last_t,
                                                    state.t_offset)
                        self._spend_rows(len(item.rows))
                        await self._room_for(len(item.rows), seq)
                        state.last_t[item.sensor] = float(item.rows[-1, 0])
                        self.services.writer.submit(Write(state, seq, samples=item))
                    else:
                        item = protocol.check_mark(message, seq, state.t_offset)
                        if self.marks_kept is None:
                            self.marks_kept = await self.services.run_db(
                                _marks_in_session, state.session_id)
                        if self.marks_kept >= MARKS_PER_SESSION_MAX:
                            raise Refused(f"mark: this session keeps {MARKS_PER_SESSION_MAX} "
                                          "marks already, the most a session keeps; this one "
                                          "is not stored", seq)
                        self.marks_kept += 1
                        self.services.writer.submit(Write(state, seq, mark=item))
                        if self.feedback is not None:
                            self.feedback.mark(item.t, item.label)
                except Refused:
                    self.services.writer.submit(Write(state, seq))  # the number is used up
                    raise
                if self.worker is not None:
                    self.worker.feed(item, received)
                while state.pending > MAX_PENDING_PER_STREAM and not self._closed:
                    await asyncio.sleep(0.01)  # storage is behind: stop reading for a while
            elif kind == "status":
                status = protocol.check_status(message, self.hello)
                status["received_at"] = time.time()
                self.services.sensor_status.setdefault(self.patient_id, {})[
                    status["sensor"]] = status
                self.services.hub.publish(self.patient_id, {"kind": "status", **status})
            elif kind == "effort_pain":  # docs/extensions/effort-pain.md
                rating = program_stream.check_effort_pain(message)
                await self.services.run_db(program_stream.store_effort_pain,
                                           state.session_id, rating)
                await self.send({"type": "effort_pain_stored", "id": rating.id})
            elif kind == "bye":
                await self._finish()
                return False
            elif kind == "hello":
                raise Refused("hello was already received on this connection")
            else:
                raise Refused(f"unknown message type {kind!r} (expected samples, mark, "
                              "points, status, effort_pain or bye)")
        except Refused as error:
            await self.refuse(error)
        return not self._closed

    async def _room_for(self, rows: int, seq: int) -> None:
        """Refuse message ``seq`` when its ``rows`` would take the session past
        ``ARMTRACK_MAX_SESSION_SAMPLES`` (its closed estimation holds every row in memory)
        or the kit past ``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY`` (``kit.daily_samples``: its
        day's rows counted from the database at its first open stream, then by its
        streams); else count them in."""
        assert self.state is not None
        if self.samples_kept is None:
            self.samples_kept, self.session_created_at = await self.services.run_db(
                _session_size_and_birth, self.state.session_id)
        kits = self.services.kit_samples
        if self.device_id not in kits:
            day = await self.services.run_db(daily_samples.day_of, self.device_id)
            kits.setdefault(self.device_id, day)  # (another stream of the kit's, meanwhile)
        limit = self.settings.max_session_samples
        if self.samples_kept + rows > limit:
            # and every later message of this stream, smaller ones and marks too: a kit
            # sends all from the first refused one on as a new session (kit-stream.js keeps
            # them all), so one stored here after it would be stored twice, out of order
            self._full_from = seq
            # not the kit's bad data: a kit streaming ahead has many messages in flight
            # when the first refusal reaches it, each refused alike; it starts a new
            # session with them, so they do not count toward ARMTRACK_REFUSED_LIMIT
            raise Refused(f"samples: this session holds {self.samples_kept} samples; "
                          f"{rows} more would pass {limit}, the most one session holds "
                          + protocol.SESSION_FULL, seq, counted=False)
        day = kits[self.device_id]
        why = daily_samples.refusal(day.total(), rows, self.settings.max_kit_samples_per_day)
        if why is not None:  # counted: a kit past its day gets nothing more in, and
            raise Refused(f"samples: {why}", seq)  # is stopped (4429) if it goes on
        self.samples_kept += rows
        day.add(self.state.session_id, self.session_created_at, rows)

    def _count(self, sensor: str, n: int, now: float) -> None:
        stats = self.sensor_stats.setdefault(sensor, {"samples": 0, "first": now})
        stats["samples"] += n
        stats["last"] = now

    async def _finish(self) -> None:
        """``bye``: store everything, ack it, close the session and process it."""
        assert self.state is not None
        self._said_bye = True
        await self.state.idle.wait()
        await self.send({"type": "ack", "seq": self.state.durable_seq})
        if await self.services.run_db(mark_closed, self.state.session_id):
            # (closed already: whoever closed it estimates it)
            self.services.process_later(self.state.session_id, DEFAULT_FILTER)
        self.services.hub.publish(self.patient_id, {"kind": "session",
                                                    "session_id": self.state.session_id,
                                                    "status": "closed"})
        await self.close(1000, "bye")

    async def _end(self, ack_task: asyncio.Task | None) -> None:
        self._closed = True
        if ack_task is not None:
            ack_task.cancel()
        state = self.state
        if self.worker is not None:
            lost = (state is not None and not self._said_bye and not state.fenced
                    and self.worker.error is None
                    and self.services.connections.get(state.stream_id) is self)
            if lost:  # the kit may resume: its live side waits for it
                self.services.park_live(state.stream_id, self.worker, self.feedback,
                                        self.device_id, self.therapist_id)
            else:
                await self.worker.close()
        if state is None:
            return
        if self.stopped is not None:
            await self._keep_stop(state.session_id)
        if self.services.connections.get(state.stream_id) is self:
            # still registered until all is done, so that a resume waits for it (ended)
            await state.idle.wait()
            try:
                if not state.fenced and await self.services.run_db(
                        _interrupt_session, state.session_id, state.stream_id,
                        state.durable_seq + 1):
                    self.services.hub.publish(self.patient_id, {
                        "kind": "session", "session_id": state.session_id,
                        "status": "interrupted"})
            except Exception as exc:  # the database locked or full: the session stays live
                # until the kit resumes it or the server restarts; the stream is let go
                log.warning("session %s not marked interrupted: %s", state.session_id, exc)
            finally:
                self.services.streams.pop(state.stream_id, None)
                self.services.connections.pop(state.stream_id, None)
        if self.websocket.application_state != WebSocketState.DISCONNECTED:
            with contextlib.suppress(Exception):
                await self.websocket.close(1000)


def _session_delay(db: DbSession, session_id: int) -> float:
    """The gyroscope delay [s] the session's kit declared (docs/extensions/gyro-delay.md);
    0 when it declared none."""
    session = db.get(models.Session, session_id)
    return 0.0 if session is None or session.gyro_delay_s is None else session.gyro_delay_s


def _reopened(db: DbSession, session_id: int) -> bool:
    """Make the session live again (a resumed or continued stream), with what ``db`` holds
    besides, committed; False, all of it rolled back, when the session is closed. One
    conditional UPDATE: a close committed on another instance after the caller's check
    (``Services.closing`` is per process) is never undone (PostgreSQL re-reads the row
    that a close changed meanwhile, or waits for the close's commit)."""
    changed = db.execute(update(models.Session)
                         .where(models.Session.id == session_id,
                                models.Session.status != "closed")
                         .values(status="live", ended_at=None)).rowcount
    if not changed:
        db.rollback()
        return False
    db.commit()
    return True


def _resumed_closed(hello: Hello, stream_id: str, next_seq: int) -> Refused:
    """The refusal of a resume whose session is closed: the kit sends the rest anew
    (closed-session/1: from ``next_seq``, what is stored)."""
    return Refused(f"hello: the session of stream {stream_id} is closed; "
                   "start a new stream (resume null)",
                   extra={"next_seq": next_seq}
                   if CLOSED_SESSION_EXTENSION in hello.extensions else None)


def _continued_closed(session_id: int) -> Refused:
    """The refusal of a stream continuing a closed session."""
    return Refused(f"hello: session {session_id} is closed; start a new session "
                   "(resume null, no session)")


def _same_kit(hello: Hello, session: models.Session, what: str) -> None:
    """Refuse ``what`` (a resumed or continued stream) whose side or sensors differ from
    the session's, or that declares another gyroscope delay: its filters run with one."""
    if set(hello.sensors) != set(session.sensors) or hello.side != session.side:
        raise Refused(f"hello: {what} must name the same side and sensors "
                      f"({session.side}; {', '.join(session.sensors)})")
    if hello.gyro_delay_s is not None and hello.gyro_delay_s != (session.gyro_delay_s or 0.0):
        had = (": its kit declared none when it began (0 s, in step)"
               if session.gyro_delay_s is None
               else f" ({session.gyro_delay_s} s, declared when it began)")
        raise Refused(f"hello: gyro_delay_s {hello.gyro_delay_s} differs from the session's"
                      f"{had}; start a new session (resume null, no session) for a kit that "
                      "declares another")


def _session_size_and_birth(db: DbSession, session_id: int) -> tuple[int, datetime]:
    """A session's sample rows and when it was created (its kit's day counts it by it)."""
    samples, created_at = db.execute(select(models.Session.samples,
                                            models.Session.created_at)
                                     .where(models.Session.id == session_id)).one()
    return samples or 0, created_at


def _marks_in_session(db: DbSession, session_id: int) -> int:
    return db.scalar(select(func.count()).select_from(models.Mark)
                     .where(models.Mark.session_id == session_id)) or 0


def _feedback_start(db: DbSession, patient_id: int, session_id: int
                    ) -> tuple[dict[str, tuple[str, float, float]], list[tuple[float, str]]]:
    """What a stream's feedback starts from: the patient's exercise bands, and the
    session's exercise marks stored so far (in time order)."""
    marks = db.execute(select(models.Mark.t, models.Mark.label)
                       .where(models.Mark.session_id == session_id,
                              models.Mark.label.contains("exercise:"))
                       .order_by(models.Mark.t, models.Mark.id)).all()
    return exercise_bands(db, patient_id), [(float(t), label) for t, label in marks]


def _interrupt_session(db: DbSession, session_id: int, stream_id: str | None = None,
                       next_seq: int | None = None) -> bool:
    """A stream that went away without ``bye``: its session may be resumed. Not when the
    stream has gone on elsewhere (stored past ``next_seq``: resumed on another instance).
    The stream keeps when (``HEARD_KEY``): its kit was heard until now, whether it sent
    data or only a hello or marks, and its silence counts from here (``store/silence.py``)."""
    stream = None
    if stream_id is not None:
        stream = db.get(models.Stream, stream_id)
        if stream is not None and stream.next_seq != next_seq:
            return False
    session = db.get(models.Session, session_id)
    if session is not None and session.status == "live":
        session.status = "interrupted"
        if stream is not None:
            stream.last_t = {**(stream.last_t or {}), HEARD_KEY: time.time()}
        db.commit()
        return True
    return False
