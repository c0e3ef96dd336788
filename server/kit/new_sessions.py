"""How many new sessions one kit token starts in an hour
(``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR``): its streamed sessions and its uploads
together, counted in the database by when the server stored them (``sessions.created_at``:
an upload's arrival, whatever time the file says it was recorded), so restarts and
instances agree. Uploads of one kit are taken one at a time in a process
(``one_upload_at_a_time``), so that a burst of them at once cannot all pass the count
before any is stored; one that comes while another is being stored is refused at once
(``BUSY``), so a burst holds no server threads waiting."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models

SETTING = "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR"

BUSY = "another upload from this kit is being stored; send this one when it is done"

_storing: set[int] = set()  # kits with an upload being counted and stored
_storing_lock = threading.Lock()


def refusal(db: DbSession, device_id: int, limit: int) -> str | None:
    """Why the kit may not start another session now (naming the setting), or None."""
    since = clock.now() - timedelta(hours=1)
    started = db.scalar(select(func.count()).select_from(models.Session).where(
        models.Session.device_id == device_id, models.Session.created_at > since))
    if started < limit:
        return None
    return (f"this kit started {started} new sessions in the last hour, the most one kit "
            f"may ({SETTING} = {limit}): keep the data and try again later")


@contextmanager
def one_upload_at_a_time(device_id: int) -> Iterator[bool]:
    """The kit's turn (in this process) for the count and the store: yields True, or
    False at once when another upload of the kit has it (the caller refuses, ``BUSY``)."""
    with _storing_lock:
        if device_id in _storing:
            taken = False
        else:
            _storing.add(device_id)
            taken = True
    if not taken:
        yield False
        return
    try:
        yield True
    finally:
        with _storing_lock:
            _storing.discard(device_id)
