"""``/ws/live?patient=ID``: a therapist's live feed of one patient, as JSON updates —
``pose`` (angles [deg], positions [m, thorax frame], segment quaternions, running range of
motion, ``latency_s`` from the newest sample's arrival to publication), ``status`` (a
sensor's battery and signal) and ``session`` (live, interrupted, closed). The therapist's
bearer token goes in the ``Authorization`` header or ``?token=``; a patient not theirs
closes with 4404 like one that does not exist."""

from __future__ import annotations

import asyncio
import contextlib
from datetime import UTC, datetime

from fastapi import APIRouter, WebSocket
from sqlalchemy import select
from starlette.websockets import WebSocketDisconnect

from ..api.deps import aware_utc
from ..auth import hash_token
from ..db import models
from ..ingest.endpoint import bearer
from ..ingest.protocol import CLOSE_BAD_TOKEN, dumps

router = APIRouter()
CLOSE_NOT_FOUND = 4404


def _therapist_patient(db, token: str | None, patient_id: int) -> str | None:
    """None when the token's therapist may watch the patient, else why not."""
    if not token:
        return "token"
    row = db.scalar(select(models.AccessToken).where(
        models.AccessToken.token_hash == hash_token(token)))
    if row is None or aware_utc(row.expires_at) <= datetime.now(UTC):
        return "token"
    patient = db.get(models.Patient, patient_id)
    if patient is None or patient.therapist_id != row.therapist_id:
        return "patient"
    return None


@router.websocket("/ws/live")
async def live(websocket: WebSocket, patient: int) -> None:
    services = websocket.app.state.services
    refusal = await services.run_db(_therapist_patient, bearer(websocket), patient)
    await websocket.accept()
    if refusal == "token":
        await websocket.close(CLOSE_BAD_TOKEN, "sign in first")
        return
    if refusal == "patient":
        await websocket.close(CLOSE_NOT_FOUND, f"no patient {patient}")
        return
    with services.hub.subscribe(patient) as subscription:
        for status in services.sensor_status.get(patient, {}).values():
            await websocket.send_text(dumps({"kind": "status", **status}))
        # the viewer sends nothing: its receive returns when it goes away, and then a
        # None in the queue ends the loop (one await per update, no task per update)
        async def watch_gone() -> None:
            with contextlib.suppress(Exception):
                await websocket.receive()
            subscription.put(None)

        gone = asyncio.create_task(watch_gone())
        try:
            while (update := await subscription.get()) is not None:
                try:
                    await websocket.send_text(dumps(update))
                except (WebSocketDisconnect, RuntimeError):
                    return
        finally:
            gone.cancel()
