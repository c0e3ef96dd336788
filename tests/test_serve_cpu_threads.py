"""``armtrack serve`` runs numpy's BLAS (OpenBLAS, MKL) and OpenMP on one thread per
calling thread unless the operator sets their own (docs/operator.md#cpu-threads): the
server's own threads (request pool, per-stream workers, export turns) and child processes
already fill the cores, and BLAS's threads on top of them oversubscribed the cores. The
N-pose's live trunk guide (240 × 240 solves and products on every ``GET /live``) took
/live from a median 20 ms to 112 ms (held 55 s: 65 → 555 ms) at load ~12 on 2 cores.

Seen from outside the real server that ``armtrack serve`` starts: the environment its
child processes were started with (Linux's ``/proc/PID/environ``), which is the server
process's own when it started them, after ``serve`` set it and before numpy was loaded;
the live estimation (``armtrack-live``) runs its BLAS calls under it."""

from __future__ import annotations

import time
from pathlib import Path

from armtrack.server.cpu_threads import THREAD_VARIABLES
from server_support import ServerProcess
from test_live_motion import _live_processes


def _environment(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace")
    return dict(item.split("=", 1) for item in raw.split("\0") if "=" in item)


def test_serve_runs_blas_on_one_thread_unless_the_operator_says_otherwise(tmp_path):
    server = ServerProcess(tmp_path)
    # as an operator's shell: none of them set, but MKL's (a value of their own)
    server.env = {k: v for k, v in server.env.items() if k not in THREAD_VARIABLES}
    server.env["MKL_NUM_THREADS"] = "3"
    server.start()
    try:
        deadline = time.monotonic() + 60
        while not (live := _live_processes(server.process.pid)):
            assert time.monotonic() < deadline, "the server started no armtrack-live process"
            time.sleep(0.2)
        seen = [{k: _environment(pid).get(k) for k in THREAD_VARIABLES} for pid in live]
        print(f"the thread settings armtrack-live was started with: {seen}")
        assert seen == [{"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                         "MKL_NUM_THREADS": "3"}] * len(live)
    finally:
        server.stop()
