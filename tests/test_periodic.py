"""``server/periodic.every``: the server's periodic rounds (kit and access rechecks,
retention, close after silence) run on after a failed round, logged, and stop when
cancelled."""

from __future__ import annotations

import asyncio
import logging

from armtrack.server.periodic import every


async def _rounds(interval_s: float, at_once: bool, wanted: int) -> tuple[list[float], bool]:
    """The times [s from the start] of ``every``'s first ``wanted`` rounds (the first
    raises), and whether the loop then ended by its cancel."""
    loop = asyncio.get_running_loop()
    start, rounds, enough = loop.time(), [], asyncio.Event()

    async def round_() -> None:
        rounds.append(loop.time() - start)
        if len(rounds) == wanted:
            enough.set()
        if len(rounds) == 1:
            raise RuntimeError("database away")

    task = asyncio.create_task(every(interval_s, round_, log=logging.getLogger("t.periodic"),
                                     failed="round failed", at_once=at_once))
    async with asyncio.timeout(10):
        await enough.wait()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    return rounds, task.cancelled()


def test_a_failed_round_is_logged_and_the_next_one_runs(caplog):
    with caplog.at_level(logging.ERROR, logger="t.periodic"):
        rounds, cancelled = asyncio.run(_rounds(0.05, False, 3))
    assert cancelled
    assert rounds[0] >= 0.049 and rounds[2] - rounds[1] >= 0.049, rounds  # every 50 ms
    failed = [r for r in caplog.records if r.name == "t.periodic"]
    assert [r.getMessage() for r in failed] == ["round failed"]
    assert failed[0].exc_info is not None and "database away" in str(failed[0].exc_info[1])


def test_at_once_runs_the_first_round_without_waiting_an_interval():
    rounds, cancelled = asyncio.run(_rounds(60.0, True, 1))  # no 60-s wait
    assert cancelled and len(rounds) == 1
