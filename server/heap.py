"""The garbage collector and a long-running server. Python's full collection walks every
container object the process holds, so with the libraries loaded (numpy, numba, scipy,
SQLAlchemy, FastAPI, viser) one took 200–300 ms on this machine, every few seconds under
load: an event loop standing still that long holds every kit's messages and every pose
(``bench/ingest.py`` found them as the pose-latency p99). Once started, what is loaded
stays: ``settle`` collects once and moves all of it out of the collector's sight
(``gc.freeze``), so later collections walk only what the running service makes."""

from __future__ import annotations

import gc

#: Allocations between young collections, and young collections between older ones
#: (Python's defaults: 700, 10, 10).
THRESHOLDS = (7000, 10, 100)


def settle() -> None:
    """Collect what start-up left, freeze what remains, and collect less often (see the
    module)."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*THRESHOLDS)
