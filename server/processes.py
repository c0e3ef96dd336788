"""The server's child processes by name: ``ps -o comm`` and ``top`` show
``armtrack-live`` (live estimation) and ``armtrack-proc`` (closed sessions' processing)
instead of another ``python``."""

from __future__ import annotations

import contextlib

LIVE_ESTIMATION = "armtrack-live"
PROCESSING = "armtrack-proc"


def name_this_process(name: str) -> None:
    """Set this process's short name (Linux; at most 15 bytes kept; elsewhere nothing)."""
    with contextlib.suppress(OSError), open("/proc/self/comm", "w") as comm:
        comm.write(name[:15])
