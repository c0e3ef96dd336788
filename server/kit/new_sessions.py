"""How many new sessions one kit token starts in an hour
(``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR``): its streamed sessions and its uploads
together, counted in the database by when the server stored them (``sessions.created_at``:
an upload's arrival, whatever time the file says it was recorded), so restarts and
instances agree.

The count and the new session's insert are one step per kit (``count_turn`` before
``refusal``, in the transaction that stores the session), whichever path (a stream's
hello, an upload) and whichever server instance: PostgreSQL takes an advisory lock of the
kit until the transaction ends, SQLite its one write lock. Uploads of one kit are taken
one at a time (``one_upload_at_a_time``: in a process, and across the processes of one
SQLite file by a lock file beside it; ``upload_turn`` across instances on PostgreSQL);
one that comes while another is being stored is refused at once (``BUSY``), so a burst
holds no server threads waiting."""

from __future__ import annotations

import errno
import fcntl
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta

from sqlalchemy import Engine, func, select, text
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session as DbSession

from .. import clock
from ..db import models

SETTING = "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR"

BUSY = "another upload from this kit is being stored; send this one when it is done"

# PostgreSQL advisory locks (two int4 keys): this class, the kit's id
COUNT_LOCK = 0x6B31  # the count and the new session's insert
#: How long a hello waits for the kit's count turn [s] (an upload's inserts may hold it)
HELLO_WAIT_S = 3.0
BUSY_HELLO = ("another new session of this kit is being stored (an upload); "
              "try again in a moment")
UPLOAD_LOCK = 0x6B32  # one upload of the kit being counted and stored

_storing: set[int] = set()  # kits with an upload being counted and stored
_storing_lock = threading.Lock()
# the lock file of each SQLite database, opened once per process and never closed: closing
# any descriptor of a file drops all the process's POSIX locks on it
_lock_files: dict[str, int] = {}


def count_turn(db: DbSession, device_id: int, wait_s: float | None = None) -> bool:
    """The kit's turn for the count (``refusal``) and the new session's insert, held until
    ``db``'s transaction ends: a hello and an upload of one kit, in any thread, process or
    instance, count one after the other, each seeing the other's session. Taken just
    before the count, released by the commit that stores the session. With ``wait_s``
    (PostgreSQL; SQLite waits its busy timeout as every writer does) False after that
    long, the transaction rolled back: an upload holds the turn through its inserts."""
    if db.get_bind().dialect.name != "postgresql":
        # SQLite: a write first takes the one write lock, so the count sees every commit
        db.execute(text("UPDATE devices SET name = name WHERE id = :d"), {"d": device_id})
        return True
    if wait_s is not None:
        db.execute(text(f"SET LOCAL lock_timeout = {max(1, round(wait_s * 1000))}"))
    try:
        db.execute(text("SELECT pg_advisory_xact_lock(CAST(:k AS integer), "
                        "CAST(:d AS integer))"), {"k": COUNT_LOCK, "d": device_id})
    except OperationalError as exc:
        if getattr(exc.orig, "sqlstate", None) != "55P03":  # lock_not_available
            raise
        db.rollback()
        return False
    if wait_s is not None:
        db.execute(text("SET LOCAL lock_timeout = DEFAULT"))
    return True


def upload_lock_file(engine: Engine) -> str | None:
    """The file whose byte ``device_id`` is locked while a kit's upload is stored, for an
    SQLite database file (its processes are one machine's); None for PostgreSQL
    (``upload_turn``) or an in-memory database."""
    url = engine.url
    if url.get_backend_name() != "sqlite" or url.database in (None, "", ":memory:"):
        return None
    return f"{url.database}-uploads"


def _lock_fd(path: str) -> int:
    with _storing_lock:
        if path not in _lock_files:
            _lock_files[path] = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        return _lock_files[path]


def upload_turn(db: DbSession, device_id: int) -> bool:
    """The kit's turn, across server instances, to have an upload counted and stored, held
    until ``db``'s transaction ends; False at once when another instance has it. On
    PostgreSQL an advisory lock; SQLite serves one process's instances only, so there
    ``one_upload_at_a_time`` is the guard and the count (``count_turn``) stays exact."""
    if db.get_bind().dialect.name != "postgresql":
        return True
    return bool(db.scalar(
        text("SELECT pg_try_advisory_xact_lock(CAST(:k AS integer), CAST(:d AS integer))"),
        {"k": UPLOAD_LOCK, "d": device_id}))


def refusal(db: DbSession, device_id: int, limit: int) -> str | None:
    """Why the kit may not start another session now (naming the setting), or None.
    Exact only after ``count_turn`` in the transaction that stores the session."""
    since = clock.now() - timedelta(hours=1)
    started = db.scalar(select(func.count()).select_from(models.Session).where(
        models.Session.device_id == device_id, models.Session.created_at > since))
    if started < limit:
        return None
    return (f"this kit started {started} new sessions in the last hour, the most one kit "
            f"may ({SETTING} = {limit}): keep the data and try again later")


@contextmanager
def one_upload_at_a_time(device_id: int, lock_file: str | None = None) -> Iterator[bool]:
    """The kit's turn for the count and the store: yields True, or False at once when
    another upload of the kit has it (the caller refuses, ``BUSY``): in this process, and
    with ``lock_file`` (``upload_lock_file``) in every process of the SQLite file too."""
    with _storing_lock:
        if device_id in _storing:
            taken = False
        else:
            _storing.add(device_id)
            taken = True
    if not taken:
        yield False
        return
    fd = None
    try:
        if lock_file is not None:
            fd = _lock_fd(lock_file)
            try:  # POSIX record lock on byte device_id: gone with the process too
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB, 1, device_id)
            except OSError as exc:
                if exc.errno not in (errno.EACCES, errno.EAGAIN):
                    raise
                fd = None
                yield False
                return
        yield True
    finally:
        if fd is not None:
            fcntl.lockf(fd, fcntl.LOCK_UN, 1, device_id)
        with _storing_lock:
            _storing.discard(device_id)
