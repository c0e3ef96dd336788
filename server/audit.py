"""The audit log: who (a therapist or a device) did what (viewed, exported, erased, …)
with which patient's data, through which route, when and from which address.

Routes need not write it themselves: ``AuditMiddleware`` gives each API request a note
(a dict in a context variable) that the dependencies fill in — ``current_therapist`` the
actor, ``own_patient`` / ``own_session`` the patient and session reached — and writes one
entry once the route has answered with success. A route that reached no patient's data
writes nothing (sign-in); a refused request writes nothing. Changes of accounts are
written by their routes with ``record``: an admin's making, disabling and enabling of an
account and issuing of a reset code, a password reset or changed.
A repeated view of the same patient's data (or of one session's) by the same actor within
``ARMTRACK_AUDIT_REPEAT_S`` is logged once, whichever routes it took (a page asks many; the
dashboard polls its live status twice a second), a repeated opening of the same live feed
too (``RepeatWindow``). Erasures by the retention task and views of
the live feed are written with ``record``."""

from __future__ import annotations

import contextvars
import hashlib
import threading
import time
from datetime import UTC, datetime
from typing import Any

from sqlalchemy.orm import Session as DbSession

from .db import models

_note: contextvars.ContextVar[dict[str, Any] | None] = contextvars.ContextVar(
    "armtrack_audit", default=None)

#: Routes whose success is a read of patient data although they name no patient.
LISTS = {("GET", "/api/patients"), ("GET", "/api/admin/patients")}
#: Export forms: a GET of one of these is ``exported``, not ``viewed``.
EXPORT_ENDINGS = (".csv", ".pdf", ".mot", ".sto", ".fhir.json", "/export")
#: The most kinds of view remembered for ``ARMTRACK_AUDIT_REPEAT_S`` (16-byte keys).
MAX_RECENT = 10_000
#: The start of the route of an account change made on the command line (``armtrack
#: create-user``), which no account makes.
CREATE_USER = "armtrack create-user"
#: Routes about the audit log itself or about accounts: never logged as data access.
NOT_LOGGED = ("/api/audit", "/api/auth/")


def note(**values: Any) -> None:
    """Add to the current request's audit note (no-op outside a request)."""
    current = _note.get()
    if current is not None:
        current.update({k: v for k, v in values.items() if v is not None})


def noted() -> dict[str, Any]:
    """What the current request's audit note holds so far: the patient and session its
    route reached (empty outside a request)."""
    return dict(_note.get() or {})


def action_of(method: str, route: str) -> str:
    if method == "DELETE" and route in ("/api/patients/{patient_id}",
                                        "/api/sessions/{session_id}"):
        return "erased"
    if method == "GET":
        if route in ("/api/patients", "/api/admin/patients"):
            return "listed"
        return "exported" if route.endswith(EXPORT_ENDINGS) else "viewed"
    if route == "/api/recordings":
        return "uploaded"
    if route == "/api/recordings/inspect":
        return "viewed"  # files looked into, nothing stored
    if route == "/api/viewer":
        return "viewed_3d"
    if route == "/api/admin/patients/{patient_id}/reassign":
        return "reassigned"
    if route == "/api/devices/{device_id}":
        return "revoked_device"
    if route == "/api/patients/{patient_id}/devices":
        return "issued_device"
    if route == "/api/patients/{patient_id}/discharge":
        return "discharged"
    if route == "/api/patients/{patient_id}/readmit":
        return "readmitted"
    return "changed"


def record(db: DbSession, *, action: str, route: str, therapist_id: int | None = None,
           device_id: int | None = None, patient_id: int | None = None,
           session_id: int | None = None, client: str | None = None,
           commit: bool = True) -> None:
    db.add(models.AuditEntry(at=datetime.now(UTC), therapist_id=therapist_id,
                             device_id=device_id, action=action, patient_id=patient_id,
                             session_id=session_id, route=route[:300],
                             client=(client or None) and client[:64]))
    if commit:
        db.commit()


class RepeatWindow:
    """Which views are the first of their kind within ``ARMTRACK_AUDIT_REPEAT_S``: kinds
    as 16-byte digests, at most ``MAX_RECENT`` (the oldest go first, to be logged again:
    more entries, never fewer). Safe to use from any thread."""

    def __init__(self) -> None:
        self._recent: dict[bytes, float] = {}  # kind's digest → its last logged view
        self._lock = threading.Lock()

    def first(self, kind: tuple, window_s: float) -> bool:
        """Whether a view of ``kind`` (what its entry would say) is to be logged now."""
        if window_s <= 0:
            return True
        key = hashlib.blake2b(repr(kind).encode("utf-8", "surrogatepass"),
                              digest_size=16).digest()
        now = time.monotonic()
        with self._lock:
            last = self._recent.get(key)
            if last is not None and now - last < window_s:
                return False
            self._recent.pop(key, None)
            self._recent[key] = now  # the newest last: the dict is in the order logged
            while len(self._recent) > MAX_RECENT:
                del self._recent[next(iter(self._recent))]
        return True


class AuditMiddleware:
    """Pure ASGI: one note per API request, written after a successful answer."""

    def __init__(self, app: Any):
        self.app = app
        self._recent = RepeatWindow()

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or not scope["path"].startswith("/api/") \
                or scope["path"].startswith(NOT_LOGGED):
            await self.app(scope, receive, send)
            return
        current: dict[str, Any] = {}
        token = _note.set(current)
        status = [500]

        async def send_status(message: dict) -> None:
            if message["type"] == "http.response.start":
                status[0] = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            _note.reset(token)
        if status[0] >= 400 or not (current.get("therapist_id") or current.get("device_id")):
            return
        route_obj = scope.get("route")
        template = getattr(route_obj, "path", scope["path"])
        method = scope["method"]
        if "patient_id" not in current and (method, template) not in LISTS:
            return
        action = action_of(method, template)
        if action in ("viewed", "listed") and not self._first_recently(scope, current, action):
            return
        client = scope.get("client")
        services = scope["app"].state.services
        await services.run_db(lambda db: record(
            db, action=action, route=f"{method} {scope['path']}",
            therapist_id=current.get("therapist_id"), device_id=current.get("device_id"),
            patient_id=current.get("patient_id"), session_id=current.get("session_id"),
            client=client[0] if client else None))

    def _first_recently(self, scope: dict, current: dict, action: str) -> bool:
        """Whether this view is the first of its kind within ``ARMTRACK_AUDIT_REPEAT_S``.
        A view's kind is who read which patient's data, and which session's: actor,
        patient, session — not the path, so that a page asking ten things of one patient
        (the patient page: the patient, sessions, summaries, progress, targets, kits, …)
        is one entry, its route the first request's. A list's kind is its path. Never the
        query string, which the entry leaves out (with it, each new query string made a
        new entry and was kept whole for the window: unbounded memory)."""
        where = (current.get("patient_id"), current.get("session_id")) \
            if action == "viewed" and "patient_id" in current else (scope["method"], scope["path"])
        return self._recent.first(
            (current.get("therapist_id"), current.get("device_id"), action, *where),
            scope["app"].state.services.settings.audit_repeat_s)
