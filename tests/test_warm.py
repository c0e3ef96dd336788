"""The compiled kernels built ahead (server/warm.py): `armtrack warm` runs every kernel
the server runs. Found by ops20 on a fresh install (user19 measured it first): the first
live session's first angle came 70 s into the exercise (load ~8.6 on 2 cores) while numba
compiled the kernels for the first time; the server now builds them at start
(tests/test_first_run.py) and `armtrack warm` at install time (docker/Dockerfile)."""

from __future__ import annotations

import json
import subprocess
import sys

#: In a fresh interpreter: `armtrack warm`, then every numba kernel of armtrack that it
#: neither ran nor reached through a kernel that ran (a kernel loaded from the cache
#: brings the kernels it calls compiled into it, which then show no signature).
SCRIPT = r"""
import gc, json, sys
from armtrack.server.cli import main
code = main(["warm"])
from numba.core.registry import CPUDispatcher

def names(code):
    out = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            out |= names(const)
    return out

kernels = [o for o in gc.get_objects() if isinstance(o, CPUDispatcher)
           and o.py_func.__module__.startswith("armtrack")
           and o.targetoptions.get("inline") != "always"]
ran = {id(k) for k in kernels if k.signatures}
while True:  # what the kernels that ran call, by the names their module binds them to
    called = set().union(*(names(k.py_func.__code__) for k in kernels if id(k) in ran))
    more = {id(k) for k in kernels if id(k) not in ran and any(
        value is k and name in called
        for name, value in vars(sys.modules[k.py_func.__module__]).items())}
    if not more:
        break
    ran |= more
print(json.dumps({"code": code, "kernels": len(kernels), "missed": sorted(
    f"{k.py_func.__module__}.{k.py_func.__qualname__}" for k in kernels if id(k) not in ran)}))
"""


def test_armtrack_warm_runs_every_kernel_the_server_runs():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    line, result = done.stdout.splitlines()[-2:]
    print("\n" + line)
    assert line.startswith("compiled kernels ready in ") and "cached for this user" in line
    result = json.loads(result)
    assert result["code"] == 0
    assert result["kernels"] >= 20, result  # numba is a dependency: the kernels exist
    assert result["missed"] == [], result
