"""A kit's stream the server stopped (docs/extensions/stream-stopped.md): after ``ready``
the ingest closes a stream 4429 when more than ``ARMTRACK_REFUSED_LIMIT`` of the kit's own
messages were refused within ``ARMTRACK_REFUSED_WINDOW_S``; the phone kit then stops for
good and asks its patient to contact the therapist. The session keeps what happened, under
its metadata's ``STOPPED_KEY`` (a dict: a recording header's values are text, so an upload
cannot forge one), and the therapist's answers say it in words."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session as DbSession

from ..db import models
from .meta_records import typed_record

STOPPED_KEY = "stopped_by_server"
#: The stored record's fields and their types (anything else is not a stop record).
FIELDS = {"at": str, "close_code": int, "reason": str, "refused": int,
          "refused_limit": int, "window_s": float, "last_refused": str}
#: Most characters of the last refused message's reason kept.
LAST_REFUSED_MAX = 300


def record_stop(db: DbSession, session_id: int, stop: dict[str, Any]) -> bool:
    """Keep ``stop`` (FIELDS) on session ``session_id`` (the newest stop replaces an older
    one); False when the session is gone (erased meanwhile)."""
    session = db.get(models.Session, session_id)
    if session is None:
        return False
    stop = {**stop, "last_refused": stop["last_refused"][:LAST_REFUSED_MAX]}
    session.meta = {**(session.meta or {}), STOPPED_KEY: stop}  # a new dict: JSON is stored
    db.commit()
    return True


def stopped_by_server(session: models.Session) -> dict[str, Any] | None:
    """The session's stop record with ``message``, the therapist's words; None when the
    server never stopped its stream. ``message`` holds only the server's words:
    ``last_refused`` quotes the kit's own values (an unknown message type, verbatim), so
    it stays apart, shown as the kit's."""
    out = typed_record(session, STOPPED_KEY, FIELDS)
    if out is None:
        return None
    out["at"] = datetime.fromisoformat(out["at"]).isoformat()
    out["message"] = (
        "The server stopped this kit's stream: it refused too many of the kit's messages "
        f"(more than {out['refused_limit']} within {out['window_s']:g} s; the server's "
        "answer to the last one is shown apart), so the kit's data are not usable as sent. "
        "The kit stopped sending and asks the patient to contact you; everything it sent "
        "before is stored, and a phone kit keeps what it did not send. Check the kit with "
        "the patient (its software, its settings, its exercise labels) before the next "
        "session, or Close the session to estimate what was recorded.")
    return out
