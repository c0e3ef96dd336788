"""Builds of costly per-session results (a session's report, its summary) that hold the
whole session in memory: one build per key at a time (a request for a key being built
waits for that build and takes its result), and at most ``at_once`` builds across keys.
A request that came for a result not kept yet built it on its own worker thread: 20 at
once for one 90k-row session built it 20 times side by side (+585 MB, another
therapist's plain request 7.6 s; tests/test_security_report_cost.py)."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from typing import TypeVar

T = TypeVar("T")

#: Builds of reports and summaries at once in one server process.
REPORT_BUILDS_AT_ONCE = 2


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

    def __init__(self, at_once: int):
        self._places = Places(at_once)
        self._lock = threading.Lock()
        self._running: dict[Hashable, Future] = {}
        self._inside = threading.local()

    def get(self, key: Hashable, build: Callable[[], T]) -> T:
        """``build()``'s result, or that of the build of ``key`` under way (its error
        too). A build is registered only once it holds its place (a build inside another
        takes none), so a request waiting for one never waits on a build that itself
        waits for a place: no two builds wait on each other."""
        depth = getattr(self._inside, "depth", 0)
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
