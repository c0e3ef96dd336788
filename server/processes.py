"""What the server's child processes share: their names (``ps -o comm`` and ``top`` show
``armtrack-live``, the live estimation, and ``armtrack-proc``, closed sessions'
processing, instead of another ``python``) and their loop over the server's requests."""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import logging
import multiprocessing
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any

LIVE_ESTIMATION = "armtrack-live"
PROCESSING = "armtrack-proc"

#: Socket buffer asked for each end of a child's pipe [bytes] (the kernel caps it at
#: ``net.core.wmem_max``/``rmem_max``): a live batch of 200 patients (~0.4 MB each way)
#: then crosses in one or two writes, not one event-loop turn per 200 KiB or less.
PIPE_BUFFER_BYTES = 4 << 20


def name_this_process(name: str) -> None:
    """Set this process's short name (Linux; at most 15 bytes kept; elsewhere nothing)."""
    with contextlib.suppress(OSError), open("/proc/self/comm", "w") as comm:
        comm.write(name[:15])


def become_child(name: str) -> None:
    """A child's start: named ``name``, and deaf to Ctrl+C (it stops the server, which
    stops its children)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    name_this_process(name)


def exit_child() -> None:
    """A child's end once its loop is done (told to stop, or the server gone): its log
    and output flushed, then ``os._exit(0)``, without the interpreter's teardown of every
    module it loaded (numpy, numba, scipy, SQLAlchemy), which nothing uses again. That
    teardown took the processing child (at ``nice`` 19) 1.1-2.5 s, up to 13 s, to end
    after it was told to stop on a busy machine (one 2-core box running tests), and every
    server's stop waited for it. What a child stores is committed before it answers the
    job; what it holds (files, sockets, its database connections) the kernel closes."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(0)


def requests(conn: Connection) -> Iterator[Any]:
    """The server's requests to a child over ``conn``, until it says stop (None) or is
    gone (the pipe closes: also when the server was killed)."""
    _die_with_parent(0)  # ready: from now on a killed server's child ends its job first
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        yield message


def spawn_child(target: Callable[..., None], *args: Any, name: str
                ) -> tuple[BaseProcess, Connection]:
    """Start ``target(conn, *args)`` in a new process (spawned: no copy of this process's
    threads) and return it with our end of the pipe. Only the child holds its end, so it
    sees ours close when we end or are killed."""
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()  # a Unix socket pair
    for conn in (ours, theirs):
        with socket.socket(fileno=conn.fileno()) as end:
            try:
                end.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, PIPE_BUFFER_BYTES)
                end.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, PIPE_BUFFER_BYTES)
            finally:
                end.detach()  # the fd stays the connection's
    # Linux's parent-death signal comes when the *thread* that started the child ends:
    # asked for only when that is the main thread (the server's event loop, which lives as
    # long as the server), never when a worker or reader thread (which may end while the
    # child still imports) starts it
    with_parent = threading.current_thread() is threading.main_thread()
    process = context.Process(
        target=_child_main, daemon=True, name=name,
        args=(os.getpid() if with_parent else 0, target.__module__, target.__qualname__,
              theirs, *args))
    process.start()
    theirs.close()
    return process, ours


#: Linux's prctl option: the signal this process gets when its parent (the thread of it
#: that started this process) ends.
PR_SET_PDEATHSIG = 1


def _child_main(parent: int, module: str, name: str, conn: Connection, *args: Any) -> None:
    """A spawned child's start, before it imports ``module`` (numpy, numba, the estimator:
    1-3 s of CPU): while it imports, it ends with the server (Linux ``PR_SET_PDEATHSIG``)
    if the server's main thread started it (``parent`` its pid; 0: not asked, since the
    signal comes when the thread that started the child ends, not the process).
    A killed server's children otherwise went on importing for seconds, beside the next
    server's, before they could see the pipe close. Once ready for requests
    (``requests``) it no longer does: a job under way when the server is killed is
    finished and stored, as before."""
    if parent:  # started by the server's main thread (0: by another thread)
        _die_with_parent(signal.SIGTERM)
        if os.getppid() != parent:  # the server ended before we asked
            os._exit(0)
    getattr(importlib.import_module(module), name)(conn, *args)


def _die_with_parent(sig: int) -> None:
    """Ask for ``sig`` when the parent ends (0: nothing); elsewhere than Linux, nothing."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)


def end_child(process: BaseProcess, conn: Connection, timeout_s: float, *,
              given_work: bool = True) -> None:
    """Tell a child to stop (None), give it ``timeout_s`` to end, else terminate it; then
    close our end (blocking: run it off the event loop). A child never given work
    (``given_work`` False) holds nothing and may still be importing what it needs (1-3 s
    after its start, the longer on a busy machine) before it would read the stop: it is
    terminated at once instead of waited for (a server stopped right after its start
    waited 1.3-2.7 s for its children's imports)."""
    if not given_work:
        process.terminate()
        process.join(timeout_s)
        conn.close()
        return
    with contextlib.suppress(OSError):
        conn.send(None)
    process.join(timeout_s)
    if process.is_alive():
        process.terminate()
        process.join(timeout_s)
    conn.close()
