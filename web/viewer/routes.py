"""The viewer's routes on the app.

* ``POST /api/viewer`` (therapist's bearer token), body ``{"patient_id": int,
  "session_id": int | null, "display_scale": float}`` (``display_scale``, optional, 0.2–1:
  how much the page scales the view down; its in-scene labels grow to read as large) — a
  one-time grant to view the patient live (``null``) or a
  stored session of theirs: ``{"url": "/viewer/<grant>/", "expires_in": 60,
  "state_url": "/api/viewer/<grant>"}`` [s] (``ARMTRACK_VIEWER_GRANT_S``).
  Another therapist's patient or session is 404. A grant, then its open view, holds one of
  the account's ``ARMTRACK_MAX_LIVE_FEEDS_PER_USER`` places (with its ``/ws/live`` feeds)
  until it lapses unused or the view closes; with all held: 429 naming the limit.
* ``GET /api/viewer/<grant>`` (the grant's therapist) — ``{"state": "waiting" | "open" |
  "closed"}``: whether the viewer's WebSocket is still to come, open, or over (then the
  page asks for a new grant); 404 once the grant is unknown (also after a restart).
* ``GET /viewer/<grant>/`` — viser's client page, for a known, unexpired, unused grant;
  else 404. Served with its own strict policy (``page.viewer_csp``).
* ``WebSocket /viewer/<grant>`` — the page's connection: it uses the grant up and is
  proxied to the loopback viser server; without a valid grant the handshake is refused
  (HTTP 403), and so it is when the right the grant was issued with is gone meanwhile.
  Once open, the view closes at once when that right goes (``server/live/access.py``):
  4401 when the sign-in that asked for the grant ended, 4404 when the patient or the
  replayed session is no longer the therapist's.
"""

from __future__ import annotations

import asyncio
from typing import Annotated, Literal

from armtrack.server.api.deps import Db, Therapist, oauth2, own_patient, own_session
from armtrack.server.auth import hash_token
from armtrack.server.live.access import Watch, refusals
from fastapi import APIRouter, Depends, HTTPException, Request, WebSocket, status
from fastapi.responses import Response
from pydantic import BaseModel, Field

from .page import client_page, viewer_csp
from .proxy import proxy
from .rom import MIN_DISPLAY_SCALE

router = APIRouter(tags=["viewer"])

#: Close code of a refused viewer WebSocket (sent as HTTP 403 before the handshake).
CLOSE_NO_GRANT = 4404


class ViewerRequest(BaseModel):
    # ids beyond 32 bits made SQLite raise OverflowError (a 500): refused with 422
    patient_id: int = Field(ge=1, le=2**31 - 1, description="the patient to view")
    session_id: int | None = Field(
        None, ge=1, le=2**31 - 1,
        description="a stored session of the patient to replay; null: the live view")
    display_scale: float = Field(
        1.0, ge=MIN_DISPLAY_SCALE, le=1.0,
        description="how much the page shows the view scaled down (its width on the page / "
                    "the view's own width); the in-scene labels grow to read as large")


class ViewerGrantOut(BaseModel):
    url: str = Field(description="the viewer page; open it within expires_in seconds, once")
    expires_in: int = Field(description="seconds the grant stays good [s]")
    state_url: str = Field(description="where to ask whether the viewer is still connected")


class ViewerStateOut(BaseModel):
    state: Literal["waiting", "open", "closed"] = Field(
        description="waiting: the viewer page has not connected yet; open: it is connected; "
                    "closed: its connection is over (ask for a new grant)")


@router.post("/api/viewer", response_model=ViewerGrantOut)
def create_viewer(body: ViewerRequest, db: Db, therapist: Therapist, request: Request,
                  token: Annotated[str | None, Depends(oauth2)]) -> ViewerGrantOut:
    """A one-time, short-lived address of a 3D view of one of your patients: live, or a
    replay of one of their stored sessions."""
    own_patient(db, therapist, body.patient_id)
    if body.session_id is not None:
        session = own_session(db, therapist, body.session_id)
        if session.patient_id != body.patient_id:
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"no session {body.session_id} of patient {body.patient_id}")
    services = request.app.state.services
    grants = services.viewer.grants
    # the grant holds one of the account's live-feed places until it lapses unused or
    # its view closes (armtrack.server.live.slots)
    slot = services.feed_slots.take(therapist.id, grants.ttl_s)
    if slot is None:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, services.feed_slots.refusal())
    grant = grants.issue(therapist_id=therapist.id, patient_id=body.patient_id,
                         session_id=body.session_id, token_hash=hash_token(token or ""),
                         display_scale=body.display_scale, slot=slot)
    return ViewerGrantOut(url=f"/viewer/{grant.id}/", expires_in=round(grants.ttl_s),
                          state_url=f"/api/viewer/{grant.id}")


@router.get("/api/viewer/{grant_id}", response_model=ViewerStateOut)
def viewer_state(grant_id: str, therapist: Therapist, request: Request) -> ViewerStateOut:
    """Whether one of your viewers is still connected: its page reloads the view with a
    new grant once it is closed (404: unknown, e.g. after a restart of the server)."""
    known = request.app.state.services.viewer.grants.state(grant_id)
    if known is None or known[0].therapist_id != therapist.id:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "no such viewer")
    return ViewerStateOut(state=known[1])


@router.get("/viewer/{grant_id}/", include_in_schema=False)
def viewer_page(grant_id: str, request: Request) -> Response:
    if request.app.state.services.viewer.grants.page(grant_id) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            "no such viewer: it was used or has expired; ask for a new one")
    plain, packed = client_page()
    zipped = "gzip" in request.headers.get("accept-encoding", "")
    headers = {"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
               "X-Frame-Options": "SAMEORIGIN", "Vary": "Accept-Encoding",
               "Content-Security-Policy": viewer_csp()}
    if zipped:
        headers["Content-Encoding"] = "gzip"
    return Response(packed if zipped else plain, media_type="text/html; charset=utf-8",
                    headers=headers)


@router.websocket("/viewer/{grant_id}")
async def viewer_socket(websocket: WebSocket, grant_id: str) -> None:
    services = websocket.app.state.services
    host = services.viewer
    grant = host.grants.claim(grant_id)
    if grant is None:
        await websocket.close(CLOSE_NO_GRANT)  # before accepting: the handshake is refused
        return
    try:
        revoked: asyncio.Future[tuple[int, str]] = asyncio.get_running_loop().create_future()
        watch = Watch(grant.token_hash, grant.therapist_id, grant.patient_id,
                      grant.session_id,
                      lambda code, reason: revoked.done() or revoked.set_result((code, reason)))
        checked_at = services.access.generation
        # the right may have gone since the grant was issued (up to its lifetime ago)
        if await services.run_db(refusals, [watch], services.settings.demo_mode):
            await websocket.close(CLOSE_NO_GRANT)
            return
        try:
            await services.access.added(watch, checked_at)
            if not revoked.done():
                await proxy(websocket, host.upstream_url(grant.ticket), revoked)
        finally:
            services.access.remove(watch)
    finally:
        host.grants.close(grant.id)
