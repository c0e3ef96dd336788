"""Exports are built on threads of their own, as many as may run at once.

Each export holds a whole session in memory (``Services.run_export``), and glibc's
allocator keeps what a thread freed in that thread's own arena: built on whichever of the
request thread pool's 40 threads was free, six exports taken in turns two at a time
spread over up to six threads and kept up to six sessions' worth (a CI-identical run under
load: report.sto six at once +491 MB against two at once +253 MB,
``test_security_report_cost``). Built on ``EXPORTS_AT_ONCE`` threads of their own they
keep at most that many, whatever else the request pool runs meanwhile (downloads, other
requests)."""

from __future__ import annotations

import asyncio
import threading
import time

from armtrack.server.services import EXPORTS_AT_ONCE, Services
from armtrack.server.settings import Settings
from starlette.concurrency import run_in_threadpool


def test_exports_are_built_on_as_many_threads_as_may_run_at_once(tmp_path):
    services = Services(Settings(data_dir=tmp_path))
    builders: set[int] = set()

    def build(db) -> None:  # an export: a while of work on its thread
        builders.add(threading.get_ident())
        time.sleep(0.05)

    async def scenario() -> None:
        stop = asyncio.Event()

        async def other_requests() -> None:  # downloads and sync routes meanwhile
            while not stop.is_set():
                await run_in_threadpool(time.sleep, 0.003)

        others = [asyncio.create_task(other_requests()) for _ in range(8)]
        await asyncio.gather(*[services.run_export(build, owner=1 + i % 3)
                               for i in range(12)])
        stop.set()
        await asyncio.gather(*others)

    try:
        asyncio.run(scenario())
    finally:
        services.engine.dispose()
    print(f"12 exports, {EXPORTS_AT_ONCE} at once, built on threads: "
          f"{len(builders)}")
    assert len(builders) <= EXPORTS_AT_ONCE


def test_an_export_cancelled_as_its_turn_is_given_gives_the_turn_back(tmp_path):
    """A request cancelled (a server shutting down, a middleware giving up) just as the
    turn it waited for was given kept that turn for good: ``EXPORTS_AT_ONCE`` such and
    every later export of the server waited forever."""
    services = Services(Settings(data_dir=tmp_path))

    async def scenario() -> tuple[int, bool]:
        turns = services.exports
        for _ in range(EXPORTS_AT_ONCE):  # every turn held: the next export waits
            await turns.acquire(99)
        never = asyncio.get_running_loop().create_future()  # its client stays
        waiting = asyncio.ensure_future(services.run_export(lambda db: None, owner=1,
                                                            gone=never))
        for _ in range(5):
            await asyncio.sleep(0)
        turns.release(99)  # the turn goes to the waiting export ...
        waiting.cancel()  # ... as its request is cancelled
        await asyncio.gather(waiting, return_exceptions=True)
        for _ in range(EXPORTS_AT_ONCE - 1):
            turns.release(99)
        free = turns._free
        try:  # and the next export still gets its turn
            await asyncio.wait_for(services.run_export(lambda db: None, owner=2), 10)
            served = True
        except TimeoutError:
            served = False
        never.cancel()
        return free, served

    try:
        free, served = asyncio.run(scenario())
    finally:
        services.export_pool.shutdown(wait=True)
        services.engine.dispose()
    print(f"turns free after the cancelled export: {free} of {EXPORTS_AT_ONCE}; "
          f"the next export served: {served}")
    assert free == EXPORTS_AT_ONCE and served
