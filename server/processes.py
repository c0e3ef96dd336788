"""What the server's child processes share: their names (``ps -o comm`` and ``top`` show
``armtrack-live``, the live estimation, and ``armtrack-proc``, closed sessions'
processing, instead of another ``python``) and their loop over the server's requests."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from multiprocessing.connection import Connection
from typing import Any

LIVE_ESTIMATION = "armtrack-live"
PROCESSING = "armtrack-proc"


def name_this_process(name: str) -> None:
    """Set this process's short name (Linux; at most 15 bytes kept; elsewhere nothing)."""
    with contextlib.suppress(OSError), open("/proc/self/comm", "w") as comm:
        comm.write(name[:15])


def become_child(name: str) -> None:
    """A child's start: named ``name``, and deaf to Ctrl+C (it stops the server, which
    stops its children)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    name_this_process(name)


def requests(conn: Connection) -> Iterator[Any]:
    """The server's requests to a child over ``conn``, until it says stop (None) or is
    gone (the pipe closes: also when the server was killed)."""
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        yield message
