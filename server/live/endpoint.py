"""``/ws/live?patient=ID``: a therapist's live feed of one patient, as JSON updates —
``pose`` (angles [deg], positions [m, thorax frame], segment quaternions, running range of
motion, ``latency_s`` from the newest sample's arrival to publication), ``status`` (a
sensor's battery and signal) and ``session`` (live, interrupted, closed). The therapist's
bearer token goes in the ``Authorization`` header or ``?token=``; a patient not theirs
closes with 4404 like one that does not exist. A feed whose right goes while it is open
(``live.access``) closes at once: 4401 when the sign-in ended, 4404 when the patient is
no longer the therapist's. One account holds at most ``ARMTRACK_MAX_LIVE_FEEDS_PER_USER``
feeds and views (``live.slots``): over it, an ``error`` update naming the limit, then close
4429; a feed gives its place back when it ends."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Annotated

from fastapi import APIRouter, Query, WebSocket
from starlette.websockets import WebSocketDisconnect

from .. import audit
from ..api.deps import therapist_of_token
from ..auth import hash_token
from ..db import models
from ..ingest.endpoint import bearer
from ..ingest.protocol import CLOSE_BAD_TOKEN, dumps
from .access import Watch, holds, no_patient
from .encoded import EncodedPose
from .slots import FeedSlots, Slot

router = APIRouter()
CLOSE_NOT_FOUND = 4404
#: Close code when the account holds all its live feeds (``ARMTRACK_MAX_LIVE_FEEDS_PER_USER``).
CLOSE_TOO_MANY = 4429
#: Live feeds opened lately, per therapist and patient: logged once a repeat window
LIVE_VIEWS = audit.RepeatWindow()


def _therapist_patient(db, token: str | None, patient_id: int, slots: FeedSlots,
                       demo_mode: bool = False, client: str | None = None,
                       repeat_s: float = 0.0) -> tuple[int, Slot] | str:
    """The id of the token's therapist and the feed's slot if they may watch the patient,
    else why not ("token", "patient", "full": the account holds all its slots)."""
    therapist = therapist_of_token(db, token, demo_mode)
    if therapist is None:  # unknown, expired, disabled (or the demo's, outside demo mode)
        return "token"
    if not holds(therapist, db.get(models.Patient, patient_id)):
        return "patient"
    slot = slots.take(therapist.id)
    if slot is None:
        return "full"
    route = f"WS /ws/live?patient={patient_id}"
    try:  # a feed opened again within ARMTRACK_AUDIT_REPEAT_S is logged once, as a view
        if LIVE_VIEWS.first((therapist.id, "viewed_live", route), repeat_s):
            audit.record(db, action="viewed_live", route=route, therapist_id=therapist.id,
                         patient_id=patient_id, client=client)
    except BaseException:
        slot.release()
        raise
    return therapist.id, slot


@router.websocket("/ws/live")
async def live(websocket: WebSocket,
               patient: Annotated[int, Query(ge=1, le=2**31 - 1)]) -> None:
    services = websocket.app.state.services
    client = websocket.client.host if websocket.client else None
    token = bearer(websocket)
    checked_at = services.access.generation
    slots = services.feed_slots
    allowed = await services.run_db(_therapist_patient, token, patient, slots,
                                    services.settings.demo_mode, client,
                                    services.settings.audit_repeat_s)
    if isinstance(allowed, str):
        await websocket.accept()
        if allowed == "token":
            await websocket.close(CLOSE_BAD_TOKEN, "sign in first")
        elif allowed == "patient":
            await websocket.close(CLOSE_NOT_FOUND, no_patient(patient))
        else:  # its words first: the page shows an error update, then the close
            with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                await websocket.send_text(dumps({"kind": "error",
                                                 "reason": slots.refusal()}))
                await websocket.close(CLOSE_TOO_MANY, slots.close_reason())
        return
    therapist_id, slot = allowed
    try:
        await websocket.accept()
        await _watched(websocket, services, token, therapist_id, patient, checked_at)
    finally:
        slot.release()  # the feed is over: its place goes back at once


async def _watched(websocket: WebSocket, services, token: str | None, therapist_id: int,
                   patient: int, checked_at: int) -> None:
    """The feed, for as long as its right holds."""
    revoked: list[tuple[int, str]] = []

    def revoke(code: int, reason: str) -> None:
        revoked.append((code, reason))
        subscription.end()

    with services.hub.subscribe(patient) as subscription:
        watch = Watch(hash_token(token or ""), therapist_id, patient, None, revoke)
        try:
            await services.access.added(watch, checked_at)
            if not revoked:
                await _feed(websocket, services, patient, subscription)
        finally:
            services.access.remove(watch)
    if revoked:
        with contextlib.suppress(WebSocketDisconnect, RuntimeError):
            await websocket.close(*revoked[0])


async def _feed(websocket: WebSocket, services, patient: int, subscription) -> None:
    """Updates to the viewer until it goes away or a None ends the subscription."""
    for status in services.sensor_status.get(patient, {}).values():
        await websocket.send_text(dumps({"kind": "status", **status}))
    # the viewer sends nothing: its receive returns when it goes away, and then a
    # None in the queue ends the loop (one await per update, no task per update)
    async def watch_gone() -> None:
        with contextlib.suppress(Exception):
            await websocket.receive()
        subscription.end()

    gone = asyncio.create_task(watch_gone())
    try:
        while (update := await subscription.get()) is not None:
            try:  # a pose comes encoded by the live estimation process
                await websocket.send_text(update.text.decode()
                                          if isinstance(update, EncodedPose)
                                          else dumps(update))
            except (WebSocketDisconnect, RuntimeError):
                return
    finally:
        gone.cancel()
