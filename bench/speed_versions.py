"""Benchmark: the estimator's speed at two revisions of the code, side by side in one run.
Run by hand: ``python bench/speed_versions.py [--base REV] [--rounds N]``. Not a test.

Issue 18 asked that the real-data work not slow the estimator by more than 20 %, measured
"previous commit against new code in one bench run". Two versions of one package cannot
share a Python process, so each measurement is a fresh process pinned to the same CPU,
importing either the base revision (a temporary ``git worktree``) or this checkout, and
the two alternate ``--rounds`` times (base, new, base, new, ...) so that a change in the
machine's speed hits both alike. Every process reads the same recording file, written once
by this checkout (format 1: both versions read it).

Measured per process (after one warm-up run, numba's compile or cache load excluded):
1. batch: ``estimate_recording`` of a 7-minute, 3-sensor, 100 Hz ``long_session``
   (42,000 rows per sensor), 9-axis and 6-axis (magnetometer dropped); median of 3 runs;
2. streaming: one 10-row chunk per sensor, ``feed`` + ``poll``, in a live pipeline 60 s
   into the session (past calibration); median over 300 rounds.

Prints each round's figures, the medians over rounds and the ratio new / base (> 1 is
slower), of the wall time and of the process's CPU time (``time.process_time``: on a
machine that other work loads, the time the scheduler gives to others does not count,
so it varies far less than the wall time; both are printed). The default base is the
last commit before issue 18's estimator work.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: The parent of 22b68e8, issue 18's first estimator commit.
DEFAULT_BASE = "6839940"

PROBE = r'''
import os, sys, json, time, statistics
for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[k] = "1"
import numpy as np
import armtrack.estimator as est
from armtrack.estimator.recording import read_recording, SensorStream
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, estimate_recording
from dataclasses import replace

path, = sys.argv[1:]
rec9 = read_recording(path)
rec6 = replace(rec9, sensors={n: SensorStream(s.t, s.acc, s.gyr, None)
                              for n, s in rec9.sensors.items()})
out = {"module": est.__file__}

def batch(rec):
    estimate_recording(rec)  # warm-up (compile or cache load)
    times, cpu = [], []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        estimate_recording(rec)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(times), statistics.median(cpu)

out["batch9_s"], out["batch9_cpu_s"] = batch(rec9)
out["batch6_s"], out["batch6_cpu_s"] = batch(rec6)

config = PipelineConfig(side=rec9.side, lengths=rec9.segment_lengths(),
                        sensors=tuple(rec9.sensors), filter="qcf")
pipe = Pipeline(config, poses=rec9.calibration)
start = 6000
for n, s in rec9.sensors.items():
    pipe.feed(n, s.t[:start], s.acc[:start], s.gyr[:start], s.mag[:start])
pipe.poll()
costs, cpu = [], []
for r in range(350):
    a, b = start + 10 * r, start + 10 * r + 10
    for n, s in rec9.sensors.items():
        t0, c0 = time.perf_counter(), time.process_time()
        pipe.feed(n, s.t[a:b], s.acc[a:b], s.gyr[a:b], s.mag[a:b])
        pipe.poll()
        if r >= 50:
            costs.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
out["chunk_us"] = statistics.median(costs) * 1e6
out["chunk_cpu_us"] = statistics.median(cpu) * 1e6
print(json.dumps(out))
'''


def package_root(checkout: Path, into: Path) -> Path:
    """A folder holding ``armtrack/{estimator,server,web}`` linked to ``checkout``'s
    top-level folders, as the installed package maps them."""
    root = into / "pkg"
    (root / "armtrack").mkdir(parents=True)
    for part in ("estimator", "server", "web"):
        (root / "armtrack" / part).symlink_to(checkout / part)
    return root


def measure(root: Path, recording: Path, cpu: int | None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_CACHE_DIR": str(root / "numba")}
    command = [sys.executable, "-c", PROBE, str(recording)]
    if cpu is not None:
        command = ["taskset", "-c", str(cpu), *command]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"the probe failed under {root}:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    expected = str(root / "armtrack" / "estimator")
    if not result["module"].startswith(expected):
        raise SystemExit(f"the probe imported {result['module']}, not {expected}: the "
                         "installed package shadows the checkout")
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default=DEFAULT_BASE, help=f"base revision ({DEFAULT_BASE})")
    parser.add_argument("--rounds", type=int, default=5, help="alternations (default 5)")
    parser.add_argument("--cpu", type=int, default=None,
                        help="pin every process to this CPU (default: the last allowed)")
    args = parser.parse_args(argv)
    cpu = args.cpu if args.cpu is not None else max(os.sched_getaffinity(0))

    sys.path.insert(0, str(REPO))
    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    base_rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.base],
                              capture_output=True, text=True, check=True).stdout.strip()
    new_rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, check=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="armtrack-speed-") as tmp:
        tmp_path = Path(tmp)
        recording = tmp_path / "long_session.csv"
        sim = simulate(SimulationConfig(exercise="long_session", seed=1))
        write_recording(sim.recording, recording)
        base_checkout = tmp_path / "base"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q",
                        str(base_checkout), args.base], check=True)
        try:
            roots = {"base": package_root(base_checkout, tmp_path / "b"),
                     "new": package_root(REPO, tmp_path / "n")}
            for root in roots.values():  # compile (or load) numba's cache once each
                measure(root, recording, cpu)
            rows: dict[str, list[dict]] = {"base": [], "new": []}
            print(f"base {base_rev} against new {new_rev} (working tree), CPU {cpu}, "
                  f"{args.rounds} rounds")
            print(f"{'round':>5} {'which':>5} {'batch 9-axis s':>15} {'batch 6-axis s':>15} "
                  f"{'10-row chunk us':>16}   (CPU: 9-axis s, 6-axis s, chunk us)")
            for r in range(args.rounds):
                for which in ("base", "new"):
                    m = measure(roots[which], recording, cpu)
                    rows[which].append(m)
                    print(f"{r + 1:>5} {which:>5} {m['batch9_s']:>15.3f} "
                          f"{m['batch6_s']:>15.3f} {m['chunk_us']:>16.1f}   "
                          f"({m['batch9_cpu_s']:.3f}, {m['batch6_cpu_s']:.3f}, "
                          f"{m['chunk_cpu_us']:.1f})", flush=True)
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(base_checkout)], check=False)
    print("\nmedians over rounds, and new / base (wall time; CPU time of the process):")
    for key, label in (("batch9_s", "batch 9-axis [s]"), ("batch6_s", "batch 6-axis [s]"),
                       ("chunk_us", "10-row chunk [us]")):
        b = statistics.median(m[key] for m in rows["base"])
        n = statistics.median(m[key] for m in rows["new"])
        cpu = key.replace("_s", "_cpu_s").replace("_us", "_cpu_us")
        cb = statistics.median(m[cpu] for m in rows["base"])
        cn = statistics.median(m[cpu] for m in rows["new"])
        print(f"  {label:<20} base {b:9.3f}  new {n:9.3f}  ratio {n / b:5.2f}   "
              f"CPU base {cb:9.3f}  new {cn:9.3f}  ratio {cn / cb:5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
