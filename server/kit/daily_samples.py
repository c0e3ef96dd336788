"""How many sample rows one kit token stores in a day (``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY``):
the rows of its sessions created in the last 24 hours, streamed and uploaded together,
counted in the database by ``sessions.created_at`` (as ``new_sessions`` counts them). A
session holds at most ``ARMTRACK_MAX_SESSION_SAMPLES`` and a kit starts at most
``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR`` an hour; without this, one token could store
~40 M rows an hour. What would pass it is refused whole, nothing stored in part."""

from __future__ import annotations

from datetime import timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models

SETTING = "ARMTRACK_MAX_KIT_SAMPLES_PER_DAY"
#: The window counted [s as a timedelta]: a kit's sessions created within it.
WINDOW = timedelta(hours=24)


def stored(db: DbSession, device_id: int) -> int:
    """Sample rows in the kit's sessions created in the last ``WINDOW``."""
    return int(db.scalar(select(func.coalesce(func.sum(models.Session.samples), 0)).where(
        models.Session.device_id == device_id,
        models.Session.created_at > clock.now() - WINDOW)) or 0)


def refusal(kept: int, more: int, limit: int) -> str | None:
    """Why ``more`` rows may not be stored by a kit holding ``kept`` rows of the last day
    (naming the setting), or None."""
    if kept + more <= limit:
        return None
    return (f"this kit stored {kept} samples in the last 24 hours; {more} more would pass "
            f"{limit}, the most one kit stores in a day ({SETTING}): not stored; the "
            "clinic can raise the limit")


def spent(kept: int, limit: int) -> str | None:
    """Why a kit holding ``kept`` rows of the last day may start no new session or stream
    (its day is spent: not one row more fits; naming the setting), or None."""
    if kept < limit:
        return None
    return (f"this kit stored {kept} samples in the last 24 hours, the most one kit stores "
            f"in a day ({SETTING} = {limit}): keep the data and try again later; the clinic "
            "can raise the limit")
