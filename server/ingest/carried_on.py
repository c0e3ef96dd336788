"""carried-on/1 (``docs/extensions/carried-on.md``): a kit's new session that carries on
its earlier one (that one full at ``ARMTRACK_MAX_SESSION_SAMPLES``, or closed by the
therapist while the kit streamed) names it in ``hello``'s ``carries_on``. The calibration
poses were held at the earlier session's start; the session page says so and why they are
not carried over. Kept in the session's metadata under ``carries_on`` (an int; left out
of an exported recording's header, ``store.recordings.header_metadata``: it names a session
of this server only)."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session as DbSession

from ..db import models
from .protocol import CLOSE_BAD_PROTOCOL, Hello, Refused

EXTENSION = "carried-on/1"
KEY = "carries_on"


def check(message: dict[str, Any], hello: Hello) -> int | None:
    """The session a new session's ``hello`` says it carries on (carried-on/1 asked, no
    ``resume``), or None; a malformed one is refused like any bad hello (4400)."""
    if EXTENSION not in hello.extensions or hello.resume is not None:
        return None
    ref = message.get(KEY)
    if ref is None:
        return None
    if isinstance(ref, int) and not isinstance(ref, bool) and 0 < ref < 2**31:
        return ref
    raise Refused(f"hello: {KEY} must be null or the id of the kit's session this one "
                  f"carries on, got {ref!r}", close_code=CLOSE_BAD_PROTOCOL)


def link(db: DbSession, session: models.Session, ref: int) -> None:
    """Note in ``session`` (new, not committed) that it carries on session ``ref``, when
    that is the same kit's session of the same patient; else nothing (an erased session:
    the stream goes on all the same)."""
    earlier = db.get(models.Session, ref)
    if (earlier is not None and earlier.id != session.id
            and earlier.device_id == session.device_id
            and earlier.patient_id == session.patient_id):
        session.meta = {**(session.meta or {}), KEY: ref}


def carries_on(session: models.Session) -> int | None:
    """The session ``session`` carries on (carried-on/1), or None."""
    ref = (session.meta or {}).get(KEY)
    return ref if isinstance(ref, int) else None
