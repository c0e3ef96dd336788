"""``server/builds.Builds``: the places of report and summary builds are given in turn.

The finding (review17): a request that builds one session after another (a patient's
``summaries?limit=200``, ``progress``, a kit's ``today``) gave its place back and took it
again at once, ahead of the requests already waiting for one (a semaphore lets the
releasing thread barge in). Two such requests kept another therapist's single build
waiting while they built on: with 200-ms builds, 9-13 s (some 50 of their builds)."""

from __future__ import annotations

import threading
import time

from armtrack.server.builds import Builds


def _cpu(seconds: float) -> None:
    """Work holding the GIL, as a report's build mostly does."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def test_a_waiting_build_gets_the_next_place_not_one_of_a_loop_that_holds_one():
    builds = Builds(2)
    started, busy, stop = [0], threading.Event(), threading.Event()

    def build() -> None:
        started[0] += 1
        if started[0] >= 4:  # both places taken, over and over
            busy.set()
        _cpu(0.02)

    def loop(name: str) -> None:  # one session after another, as summaries?limit=200
        for i in range(10_000):
            if stop.is_set():
                return
            builds.get((name, i), build)

    loops = [threading.Thread(target=loop, args=(n,)) for n in ("first", "second")]
    for thread in loops:
        thread.start()
    try:
        assert busy.wait(30), "the loops' builds did not start"
        asked = started[0]
        began = time.perf_counter()
        seen = builds.get(("another", 0), lambda: started[0])
        waited = time.perf_counter() - began
    finally:
        stop.set()
        for thread in loops:
            thread.join()
    ahead = seen - asked
    print(f"\nthe other build waited {waited:.2f} s, while the loops began {ahead} builds")
    # the two builds under way, and at most one more begun as the first place freed
    assert ahead <= 3, f"{ahead} builds of the loops went ahead of one already waiting"
