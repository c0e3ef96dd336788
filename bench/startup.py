"""Benchmark: how long the ``armtrack`` commands take to start, as a user meets them (a whole
new process each time). Run by hand: ``python bench/startup.py [--runs N]``. Not a test.

1. Whole-process wall time, median of ``--runs`` runs (after one warm-up run, so the files
   are in the page cache), of the light commands, against the aim of 0.5 s:
   ``armtrack --help``, ``armtrack check`` of a 35 s simulated recording, ``armtrack pose``
   of one set of angles, ``armtrack create-user`` on an already-migrated SQLite database
   (the migration of a new database and the password hash are real work: they are timed
   apart, the first as ``create-user`` on a fresh database, the second in this process).
2. The heavy commands (``estimate`` of the same recording, ``simulate``, ``serve`` up to its
   first answer) whole-process, and where their start-up goes: the same command under
   ``python -X importtime``, the imports' cumulative times grouped by top-level package
   (numpy, scipy, numba, pyarrow, sqlalchemy, fastapi, ...; armtrack's own modules apart),
   so what remains is the command's work.

``--python`` picks the interpreter (another checkout's ``.venv/bin/python`` benchmarks that
checkout: the "before" figures of a change). Results go to ``bench/results/startup.csv``
(one row per command and run set, appended) and are printed as a table.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import datetime as dt
import os
import re
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import defaultdict
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "startup.csv"
AIM_S = 0.5
#: Packages whose import time is reported by name; everything else is "other".
NAMED = ("numpy", "scipy", "numba", "llvmlite", "pyarrow", "sqlalchemy", "alembic", "fastapi",
         "starlette", "pydantic", "pydantic_settings", "uvicorn", "websockets", "viser",
         "matplotlib", "argon2", "msgspec", "orjson")


def _git_commit(python: str) -> str:
    """The commit of the checkout ``python``'s armtrack comes from (``?`` if unknown)."""
    where = subprocess.run([python, "-c", "import armtrack.server, os; "
                            "print(os.path.dirname(os.path.realpath(armtrack.server.__path__[0])))"],
                           capture_output=True, text=True).stdout.strip()
    out = subprocess.run(["git", "-C", where or ".", "rev-parse", "--short", "HEAD"],
                         capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", where or ".", "status", "--porcelain", "--",
                            "server", "estimator"], capture_output=True, text=True).stdout
    return out.stdout.strip() + ("+changes" if dirty.strip() else "") or "?"


def _time(cmd: list[str], env: dict, stdin: str | None = None) -> tuple[float, float]:
    """(wall, CPU) time [s] of one run of ``cmd``; CPU is user + system time of the process
    and its children, which a loaded machine inflates much less than the wall time."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, input=stdin, capture_output=True, text=True)
    took = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return took, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _median(cmd_for_run, env: dict, runs: int) -> tuple[float, float, float, float]:
    """(median, min, max) wall time and median CPU time [s] over ``runs`` runs after a
    warm-up; ``cmd_for_run(i)`` gives the i-th command line (create-user needs a new name
    each run)."""
    _time(cmd_for_run(-1), env)
    runs_ = [_time(cmd_for_run(i), env) for i in range(runs)]
    walls = [w for w, _ in runs_]
    return (statistics.median(walls), min(walls), max(walls),
            statistics.median(c for _, c in runs_))


def _imports(cmd: list[str], env: dict) -> dict[str, float]:
    """Import time [s] by top-level package of ``cmd`` (a ``-m`` command line) run under
    ``-X importtime``."""
    done = subprocess.run([cmd[0], "-X", "importtime", *cmd[1:]], env=env,
                          capture_output=True, text=True)
    return _by_package(done.stderr)


def _by_package(importtime: str) -> dict[str, float]:
    """The self times of ``-X importtime``'s report summed by top-level package [s];
    armtrack's own modules as ``armtrack``, packages not in NAMED as ``other``."""
    totals: dict[str, float] = defaultdict(float)
    # lines: "import time: self [us] | cumulative | imported package", nesting by indent
    for line in importtime.splitlines():
        match = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if not match:
            continue
        self_us, name = int(match.group(1)), match.group(4)
        top = name.split(".")[0]
        group = top if top in NAMED or top == "armtrack" else "other"
        totals[group] += self_us / 1e6  # self times add up without double counting
    return dict(totals)


def _serve_time(python: str, env: dict, data_dir: Path,
                importtime: bool = False) -> tuple[float, dict[str, float]]:
    """Wall time from ``armtrack serve`` to its first answer on ``/`` [s], and with
    ``importtime`` its imports by package (else empty)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    start = time.perf_counter()
    log = tempfile.TemporaryFile("w+")
    proc = subprocess.Popen([python, *(["-X", "importtime"] if importtime else []),
                             "-m", "armtrack.server.cli", "serve", "--port", str(port),
                             "--data-dir", str(data_dir)], env=env,
                            stdout=subprocess.DEVNULL, stderr=log)
    try:
        while True:
            with contextlib.suppress(OSError):
                urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=1).read()
                took = time.perf_counter() - start
                proc.terminate()
                try:
                    proc.wait(120)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                log.seek(0)
                return took, _by_package(log.read()) if importtime else {}
            if proc.poll() is not None:
                raise SystemExit("armtrack serve exited before answering")
            if time.perf_counter() - start > 600:
                raise SystemExit("armtrack serve did not answer within 600 s")
            time.sleep(0.02)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python", default=sys.executable,
                        help="the interpreter whose armtrack is measured (default this one)")
    parser.add_argument("--runs", type=int, default=7, help="runs per command (default 7)")
    parser.add_argument("--label", default="", help="a note stored with the rows")
    parser.add_argument("--no-write", action="store_true", help="print only, no CSV rows")
    parser.add_argument("--no-serve", action="store_true",
                        help="leave out `serve` (minutes on a loaded machine)")
    args = parser.parse_args()
    py = args.python
    cli = [py, "-m", "armtrack.server.cli"]
    commit = _git_commit(py)
    rows: list[dict] = []

    with tempfile.TemporaryDirectory(prefix="armtrack-startup-") as tmp:
        tmp = Path(tmp)
        env = {**os.environ, "ARMTRACK_DATA_DIR": str(tmp / "data")}
        recording = tmp / "elbow.csv"
        subprocess.run([*cli, "simulate", "--exercise", "elbow_flexion", "-o", str(recording)],
                       env=env, check=True, capture_output=True)
        migrated = tmp / "migrated"
        subprocess.run([*cli, "create-user", "first", "--password", "a-long-password",
                        "--data-dir", str(migrated)], env=env, check=True, capture_output=True)

        def fresh_db(i: int) -> list[str]:
            return [*cli, "create-user", "first", "--password", "a-long-password",
                    "--data-dir", str(tmp / f"fresh{i}")]

        light = {
            "--help": lambda i: [*cli, "--help"],
            "check": lambda i: [*cli, "check", str(recording)],
            "pose": lambda i: [*cli, "pose", "shoulder_abduction=90", "elbow_flexion=45"],
            "create-user (migrated db)": lambda i: [
                *cli, "create-user", f"user{i + 1}", "--password", "a-long-password",
                "--data-dir", str(migrated)],
        }
        heavy = {
            "create-user (new db: + migration)": fresh_db,
            "estimate": lambda i: [*cli, "estimate", str(recording), "-o", str(tmp / "a.csv")],
            "simulate": lambda i: [*cli, "simulate", "-o", str(tmp / f"s{i}.csv")],
        }
        for group, commands in (("light", light), ("heavy", heavy)):
            for name, cmd in commands.items():
                median, low, high, cpu = _median(cmd, env, args.runs)
                parts = _imports(cmd(100 + args.runs), env)
                rows.append({"command": name, "group": group, "median_s": median,
                             "min_s": low, "max_s": high, "cpu_s": cpu, "imports": parts})
                print(f"  {name}: wall {median:.3f} s, CPU {cpu:.3f} s", flush=True)
        serve_times = []
        if not args.no_serve:
            _serve_time(py, env, tmp / "serve")  # the first run migrates a new database
            serve_times = [_serve_time(py, env, tmp / "serve")[0]
                           for _ in range(max(3, args.runs // 2))]
        if serve_times:
            rows.append({"command": "serve (to first answer)", "group": "heavy",
                         "median_s": statistics.median(serve_times), "min_s": min(serve_times),
                         "max_s": max(serve_times), "cpu_s": float("nan"),
                         "imports": _serve_time(py, env, tmp / "serve", importtime=True)[1]})
        # the password hash alone (argon2, in this process when armtrack's is importable)
        hash_s = subprocess.run(
            [py, "-c", "import time; from armtrack.server.auth import hash_password; "
             "hash_password('warm'); t = time.perf_counter(); hash_password('a-long-password');"
             " print(time.perf_counter() - t)"], env=env, capture_output=True, text=True)
        hash_time = float(hash_s.stdout.strip() or "nan")

    print(f"armtrack at {commit}, {args.runs} runs each (median, min–max), python {py}")
    load = os.getloadavg()[0]
    print(f"load average at the end: {load:.1f} on {os.cpu_count()} CPUs"
          + (" (busy: read the CPU column)" if load > (os.cpu_count() or 1) else ""))
    print(f"{'command':<36}{'wall s':>8}{'min':>7}{'max':>7}{'CPU s':>7}  imports (s, self "
          "times by package)")
    for row in rows:
        aim = (" ok" if min(row["median_s"], row["cpu_s"]) < AIM_S else " OVER")  \
            if row["group"] == "light" else ""
        parts = sorted(row["imports"].items(), key=lambda kv: -kv[1])
        shown = ", ".join(f"{k} {v:.2f}" for k, v in parts if v >= 0.01)
        print(f"{row['command']:<36}{row['median_s']:8.3f}{row['min_s']:7.3f}"
              f"{row['max_s']:7.3f}{row['cpu_s']:7.3f}{aim}  {shown}")
    print(f"{'argon2 password hash alone':<36}{hash_time:9.3f}")
    if args.no_write:
        return
    RESULTS.parent.mkdir(exist_ok=True)
    new = not RESULTS.exists()
    with RESULTS.open("a", newline="") as file:
        writer = csv.writer(file)
        if new:
            writer.writerow(["date", "commit", "label", "command", "runs", "median_s", "min_s",
                             "max_s", "cpu_s", "load", "imports_s"])
        today = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%MZ")
        for row in rows:
            writer.writerow([today, commit, args.label, row["command"], args.runs,
                             f"{row['median_s']:.3f}", f"{row['min_s']:.3f}",
                             f"{row['max_s']:.3f}", f"{row['cpu_s']:.3f}", f"{load:.1f}",
                             " ".join(f"{k}={v:.3f}" for k, v in sorted(row["imports"].items())
                                      if v >= 0.001)])
        writer.writerow([today, commit, args.label, "argon2 hash (in process)", 1,
                         f"{hash_time:.3f}", "", "", "", f"{load:.1f}", ""])
    print(f"appended to {RESULTS}")


if __name__ == "__main__":
    main()
