"""How many threads numpy's BLAS (OpenBLAS, MKL) and OpenMP start in armtrack's
processes: one per calling thread, unless the operator set their own.

The server already spreads its CPU work over threads (request pool, per-stream workers,
export turns) and child processes (live estimation, closed sessions' processing); each
BLAS call taking all the cores again on top of them oversubscribes the machine, and on a
busy one its threads wait on each other: the N-pose's live trunk guide (240 × 240 solves
and products on each ``GET /live``) took /live from a median 20 ms to 112 ms at load ~12
on 2 cores (docs/performance.md). The libraries read these variables once, when numpy is
first imported: ``one_blas_thread`` must run before that (``armtrack``'s commands import
numpy inside their ``run``)."""

from __future__ import annotations

import os
from collections.abc import MutableMapping

#: The variables the BLAS and OpenMP runtimes numpy may load read for their thread count.
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread(environ: MutableMapping[str, str] = os.environ) -> None:
    """Each of ``THREAD_VARIABLES`` not set in ``environ`` set to 1 (a value the operator
    gave wins). Before numpy's first import; child processes inherit it."""
    for name in THREAD_VARIABLES:
        environ.setdefault(name, "1")
