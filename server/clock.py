"""The server's clock: ``now()`` is the current time, timezone-aware UTC.

Everything that dates a session or decides what "today" is (sessions' start and end,
programs' versions, adherence weeks, flags) reads it here, so that a test can run the
server on a simulated calendar: a test server's process replaces ``now`` before it
serves (``tests/server_support.py``'s zygote preamble). Callers use ``clock.now()``,
never ``from clock import now``, so the replacement reaches them.
"""

from __future__ import annotations

from datetime import UTC, datetime


def now() -> datetime:
    """The current time [UTC, aware]."""
    return datetime.now(UTC)
