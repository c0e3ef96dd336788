"""``armtrack warm``: build the compiled kernels now, as the server's user, so that the
first patient after an install or an upgrade does not wait for them (``server/warm.py``).
The server builds them at start too, on idle CPU time; this is for an install step (the
Docker image runs it as it is built)."""

from __future__ import annotations

import argparse

HELP = "build the compiled kernels ahead (the first session after an install waits less)"
DESCRIPTION = ("Runs the server's estimation on three short simulated sessions so that "
               "numba compiles armtrack's kernels and caches them for this user "
               "(NUMBA_CACHE_DIR, else beside an editable checkout's source, else "
               "$XDG_CACHE_HOME or ~/.cache, then armtrack/numba). Run it as the user the "
               "server runs as. A fresh install takes a minute or two; a cached one a "
               "second or two. See docs/operator.md.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    from armtrack.server.cpu_threads import one_blas_thread

    one_blas_thread()  # as the server runs them (docs/operator.md#cpu-threads)
    from armtrack.estimator.arm import compiled
    from armtrack.server.warm import warm

    seconds = warm()
    # where numba put one module's kernels (the others' are beside it, or in the
    # __pycache__ beside their source files)
    cache = getattr(getattr(compiled.kernel, "_cache", None), "_cache_path", None)
    print(f"compiled kernels ready in {seconds:.1f} s"
          + (f" (cached for this user, e.g. in {cache})" if cache else
             " (numba is not installed: armtrack runs its pure-Python kernels)"))
    return 0
