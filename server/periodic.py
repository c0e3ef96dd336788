"""Periodic rounds in the server's event loop: the kit and access rechecks
(``services.py``, ``live/access.py``), the retention's erasures and the close after
silence (``app.py``)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any


async def every(interval_s: float, round_: Callable[[], Awaitable[Any]], *,
                log: logging.Logger, failed: str, at_once: bool = False) -> None:
    """Run ``round_`` every ``interval_s`` seconds until cancelled: the first round at once
    with ``at_once``, else after one interval. A round that raises is logged (``failed``,
    with its traceback) and the next one comes as planned: the loop never dies of it (a
    database busy or away for a while)."""
    if not at_once:
        await asyncio.sleep(interval_s)
    while True:
        try:
            await round_()
        except Exception:  # a failed round is tried again at the next one
            log.exception(failed)
        await asyncio.sleep(interval_s)
