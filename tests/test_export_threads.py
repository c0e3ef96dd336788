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
