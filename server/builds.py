"""Builds of costly per-session results (a session's report, its summary) that hold the
whole session in memory: one build per key at a time (a request for a key being built
waits for that build and takes its result), and at most ``at_once`` builds across keys.
A request that came for a result not kept yet built it on its own worker thread: 20 at
once for one 90k-row session built it 20 times side by side (+585 MB, another
therapist's plain request 7.6 s; tests/test_security_report_cost.py).

A request waits for a build holding one of the server's 40 worker threads and, on
PostgreSQL, its database connection (pool 5 + 10): one account's 45 requests for one
session's summary held them all, other therapists' requests failing after the pool's 30-s
wait (att18, tests/test_security_build_waiters.py). So one caller (a therapist account,
all its sign-ins; a kit) has at most ``PER_CALLER`` requests building or waiting at once,
and all callers together ``AT_ONCE``: the next is refused at once (``BuildsBusy``: 429,
or 503 when the server's places are taken, with ``Retry-After``)."""

from __future__ import annotations

import contextvars
import threading
from collections import deque
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from typing import TypeVar

T = TypeVar("T")

#: Builds of reports and summaries at once in one server process.
REPORT_BUILDS_AT_ONCE = 2
#: Requests of one caller (a therapist account, a kit) building or waiting for a build at
#: once in one server process; a page asks for at most three at once.
PER_CALLER = 4
#: Requests of all callers building or waiting for a build at once in one server process:
#: each holds a worker thread (of 40) and on PostgreSQL a database connection (of 15).
AT_ONCE = 8
#: Seconds a refused caller waits before asking again (``Retry-After``).
RETRY_AFTER_S = 5

#: Set (to True) where builds are not counted against a caller: an export's own thread,
#: whose turns (``server/export_turns.py``) bound them already.
UNCOUNTED: contextvars.ContextVar[bool] = contextvars.ContextVar("armtrack_builds_uncounted",
                                                                 default=False)


class BuildsBusy(Exception):
    """Too many requests building or waiting for a build: ``status`` 429 (this caller's)
    or 503 (the server's), ``detail`` in words."""

    def __init__(self, status: int, detail: str):
        super().__init__(detail)
        self.status = status
        self.detail = detail


def caller() -> tuple[str, int] | None:
    """Who the current request is, as its audit note says: a therapist account or a kit
    (None outside a request, and on an export's thread)."""
    if UNCOUNTED.get():
        return None
    from .audit import noted
    note = noted()
    if note.get("therapist_id") is not None:
        return ("therapist", note["therapist_id"])
    if note.get("device_id") is not None:
        return ("kit", note["device_id"])
    return None


class Places:
    """``count`` places, given in turn: a place given back goes to the thread that has
    waited longest, never to one that asks again at once. (A semaphore let a request that
    builds one session after another, as a patient's ``summaries?limit=200``, give its
    place back and take it again ahead of those waiting: two such requests kept another
    therapist's single build waiting while they built on; ``tests/test_builds.py``.)"""

    def __init__(self, count: int):
        self._free = count
        self._lock = threading.Lock()
        self._waiting: deque[threading.Event] = deque()

    def acquire(self) -> None:
        with self._lock:
            if self._free and not self._waiting:
                self._free -= 1
                return
            given = threading.Event()
            self._waiting.append(given)
        given.wait()  # the place was handed over by ``release``

    def release(self) -> None:
        with self._lock:
            if self._waiting:
                self._waiting.popleft().set()
            else:
                self._free += 1


class Builds:
    """One build per key at a time, at most ``at_once`` at once (the places given in
    turn); a build that needs another inside it (a summary needs the session's report)
    takes no second place."""

    def __init__(self, at_once: int, per_caller: int = PER_CALLER, waiting: int = AT_ONCE):
        self._places = Places(at_once)
        self._lock = threading.Lock()
        self._running: dict[Hashable, Future] = {}
        self._inside = threading.local()
        self.per_caller, self.waiting = per_caller, waiting
        self._callers: dict[tuple[str, int], int] = {}

    def _enter(self, who: tuple[str, int]) -> None:
        """Count ``who``'s request in, or raise ``BuildsBusy``."""
        with self._lock:
            mine = self._callers.get(who, 0)
            if mine >= self.per_caller:
                account = "this account" if who[0] == "therapist" else "this kit"
                raise BuildsBusy(429, f"{account} has {self.per_caller} reports or summaries "
                                 "being made at once, the most it may: ask again in "
                                 f"{RETRY_AFTER_S} s, once one has come")
            if sum(self._callers.values()) >= self.waiting:
                raise BuildsBusy(503, f"the server is making {self.waiting} reports or "
                                 "summaries at once, the most it makes: ask again in "
                                 f"{RETRY_AFTER_S} s")
            self._callers[who] = mine + 1

    def _leave(self, who: tuple[str, int]) -> None:
        with self._lock:
            if (left := self._callers[who] - 1) > 0:
                self._callers[who] = left
            else:
                del self._callers[who]

    def get(self, key: Hashable, build: Callable[[], T]) -> T:
        """``build()``'s result, or that of the build of ``key`` under way (its error
        too). A build is registered only once it holds its place (a build inside another
        takes none), so a request waiting for one never waits on a build that itself
        waits for a place: no two builds wait on each other. A request (``caller``) past
        its own or the server's count of requests building or waiting raises
        ``BuildsBusy`` at once, holding nothing."""
        depth = getattr(self._inside, "depth", 0)
        who = caller() if depth == 0 else None
        if who is None:
            return self._get(key, build, depth)
        self._enter(who)
        try:
            return self._get(key, build, depth)
        finally:
            self._leave(who)

    def _get(self, key: Hashable, build: Callable[[], T], depth: int) -> T:
        with self._lock:
            running = self._running.get(key)
        if running is not None:
            return running.result()
        held = depth == 0  # a build inside another takes no place of its own
        if held:
            self._places.acquire()
        try:
            with self._lock:
                running = self._running.get(key)
                if running is None:
                    mine = self._running[key] = Future()
            if running is not None:  # begun while this one waited for its place
                if held:
                    self._places.release()
                    held = False
                return running.result()
            self._inside.depth = depth + 1
            try:
                value = build()
            except BaseException as exc:
                mine.set_exception(exc)
                raise
            finally:
                self._inside.depth = depth
                with self._lock:
                    del self._running[key]
            mine.set_result(value)
            return value
        finally:
            if held:
                self._places.release()


#: The server's builds of session reports and summaries.
REPORTS = Builds(REPORT_BUILDS_AT_ONCE)
