"""An interrupted session closed by the server after a long silence
(docs/extensions/closed-after-silence.md). A kit switched off without a ``bye`` leaves its
session ``interrupted``: it may resume, so it is neither estimated nor flagged, and stayed
so until the therapist closed it. After ``ARMTRACK_CLOSE_INTERRUPTED_AFTER_HOURS`` (168 h)
with no data from it, the server closes it as the therapist's Close would: every stored
sample stays (acked data are never touched), the session is estimated, and a late resume
is refused as for any closed session (``ingest.md``'s error; with ``closed-session/1`` its
``next_seq``, and the kit sends the rest as a new session). The session keeps what
happened under its metadata's ``SILENCE_KEY`` (a dict: an upload's header values are text,
so it cannot forge one). Silence is counted from when the server last heard the kit
(``silent_since``: data, or a connection of it open) and only while the server is up
(``app.close_silent_sessions``)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session as DbSession

from .. import audit, clock
from ..db import models
from ..ingest.writer import HEARD_KEY, SEEN_PREFIX
from .meta_records import typed_record

SILENCE_KEY = "closed_after_silence"
#: The stored record's fields and their types (anything else is not such a record).
FIELDS = {"at": str, "last_data_at": str, "after_hours": float}


def silent_since(db: DbSession, session: models.Session) -> float:
    """When the server last heard the session's kit [s, Unix time]: its last stored data
    or, later, when a stream of it lost its connection without a
    ``bye`` (``writer.HEARD_KEY``: a kit that resumed and sent only a hello or marks, or
    kept its socket open sending nothing, was heard until then)."""
    return last_times(db, session)[1]


def last_times(db: DbSession, session: models.Session) -> tuple[float, float]:
    """(when the session last stored data from its kit, ``silent_since``) [s, Unix time],
    from one read of its streams: the data's time is the newest of its streams' stored
    arrival times (``writer.SEEN_PREFIX``); for a session with none kept (no row stored,
    or rows stored before they were kept), its start."""
    started = session.started_at  # SQLite gives naive UTC back
    data = (started if started.tzinfo else started.replace(tzinfo=UTC)).timestamp()
    heard = data
    for (last_t,) in db.execute(select(models.Stream.last_t)
                                .where(models.Stream.session_id == session.id)):
        for key, at in (last_t or {}).items():
            if not isinstance(at, int | float):
                continue
            if key.startswith(SEEN_PREFIX):
                data = max(data, float(at))
            elif key == HEARD_KEY:
                heard = max(heard, float(at))
    return data, max(data, heard)


def silent_sessions(db: DbSession, cutoff: float) -> list[int]:
    """The interrupted sessions whose kit was not heard since ``cutoff`` [s, Unix time]
    (``silent_since``), oldest first."""
    sessions = db.scalars(select(models.Session).where(models.Session.status == "interrupted")
                          .order_by(models.Session.id)).all()
    return [s.id for s in sessions if silent_since(db, s) < cutoff]


def close_silent(db: DbSession, session_id: int, cutoff: float, hours: float) -> bool:
    """Close session ``session_id`` if it is still interrupted and its kit not heard since
    ``cutoff`` [s, Unix time] (``silent_since``), keeping the record (committed): True
    when this closed it. One conditional UPDATE: a resume that made it live first (any
    instance) keeps it live; a resume after it finds it closed and is refused
    (``endpoint._reopened``)."""
    session = db.get(models.Session, session_id)
    if session is None or session.status != "interrupted":
        return False
    last, heard = last_times(db, session)
    if heard >= cutoff:
        return False
    now = clock.now()
    record = {"at": now.isoformat(), "after_hours": float(hours),
              "last_data_at": datetime.fromtimestamp(last, now.tzinfo).isoformat()}
    meta = {**(session.meta or {}), SILENCE_KEY: record}
    changed = db.execute(update(models.Session)
                         .where(models.Session.id == session_id,
                                models.Session.status == "interrupted")
                         .values(status="closed", ended_at=now, meta=meta)).rowcount
    if changed:  # in the audit log, with the close, as the retention's erasures are
        audit.record(db, action="closed_silence", route="silence",
                     patient_id=session.patient_id, session_id=session_id, commit=False)
    db.commit()
    return bool(changed)


def closed_after_silence(session: models.Session) -> dict[str, Any] | None:
    """The session's record with ``message``, the therapist's words; None when the server
    did not close it."""
    out = typed_record(session, SILENCE_KEY, FIELDS)
    if out is None:
        return None
    out["message"] = (
        f"The server closed this session: its kit sent nothing for {out['after_hours']:g} "
        "hours after the stream broke off without a goodbye (switched off, or out of "
        "reach). Everything it sent is stored and estimated. A kit that comes back with "
        "more of this session sends it as a new session.")
    return out
