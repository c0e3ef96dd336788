"""How many sample rows one kit token stores in a day (``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY``):
the rows of its sessions created in the last 24 hours, streamed and uploaded together,
counted in the database by ``sessions.created_at`` (as ``new_sessions`` counts them). A
session holds at most ``ARMTRACK_MAX_SESSION_SAMPLES`` and a kit starts at most
``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR`` an hour; without this, one token could store
~40 M rows an hour. What would pass it is refused whole, nothing stored in part."""

from __future__ import annotations

import heapq
import threading
from datetime import UTC, datetime, timedelta

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


def _aware(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)  # SQLite: naive UTC


class KitDay:
    """One kit's rows of the last day as this instance counts them while the kit has a
    stream open (``Services.kit_samples``): per session its creation time and rows, read
    from the database at the kit's first stream (``day_of``), then what its streams and
    uploads add. A session leaves the count ``WINDOW`` after it was created, as it leaves
    ``stored``'s: a socket open for more than a day no longer holds its first sessions'
    rows against the kit. Read on database threads (a hello's check) as well as on the
    event loop, so one thread at a time (two taking the aged sessions out of the heap at
    once took out each other's: the day miscounted); O(log n) a call."""

    def __init__(self, sessions: dict[int, tuple[datetime, int]] | None = None):
        self._lock = threading.Lock()
        self._rows: dict[int, int] = {}
        self._born: list[tuple[datetime, int]] = []  # (created_at [UTC], session id), a heap
        self._total = 0
        for session_id, (created_at, rows) in (sessions or {}).items():
            self.add(session_id, created_at, rows)

    def total(self) -> int:
        """Rows of the kit's sessions created in the last ``WINDOW`` (by ``clock.now``)."""
        since = clock.now() - WINDOW
        with self._lock:
            while self._born and self._born[0][0] <= since:
                _, session_id = heapq.heappop(self._born)
                self._total -= self._rows.pop(session_id)
            return self._total

    def add(self, session_id: int, created_at: datetime, rows: int) -> None:
        """``rows`` more stored in session ``session_id`` (created at ``created_at``);
        nothing for a session already out of the window."""
        created_at = _aware(created_at)
        since = clock.now() - WINDOW
        with self._lock:
            if session_id not in self._rows:
                if created_at <= since:
                    return
                self._rows[session_id] = 0
                heapq.heappush(self._born, (created_at, session_id))
            self._rows[session_id] += rows
            self._total += rows

    def hold(self, session_id: int, created_at: datetime, rows: int) -> None:
        """Session ``session_id`` (created at ``created_at``) holds ``rows`` in all: an
        upload, stored whole, counted once whether the kit's day was read from the
        database before its commit or after it (with it)."""
        with self._lock:
            if session_id in self._rows:
                self._total += rows - self._rows[session_id]
                self._rows[session_id] = rows
                return
        self.add(session_id, created_at, rows)


def day_of(db: DbSession, device_id: int) -> KitDay:
    """The kit's day as the database holds it: its sessions created in the last
    ``WINDOW`` with their rows."""
    rows = db.execute(select(models.Session.id, models.Session.created_at,
                             models.Session.samples).where(
        models.Session.device_id == device_id,
        models.Session.created_at > clock.now() - WINDOW))
    return KitDay({session_id: (created_at, samples or 0)
                   for session_id, created_at, samples in rows})
