"""Benchmark: the estimator's speed on one core. Run by hand:
``python bench/speed.py [--quick]``. Not a test.

1. Batch: a 30-minute, 3-sensor (upper_arm, forearm, hand), 9-axis, 100 Hz recording
   (540,000 sensor rows) through the whole pipeline, ``estimate_recording``, from a
   ``Recording`` in memory (reading the file is ``bench/recording_read.py``'s business).
   Target: under 0.5 s. Then where the time goes: the pipeline's stages timed by wrapping
   the estimator's functions for the length of a run (exclusive times; the product code is
   not changed), and the profiler's busiest functions.
2. ``qcf`` alone on the same rows, side by side with what a user would pick instead:
   VQF's C++ ``updateBatch``, imufusion's ``Ahrs`` called per sample and our pure-Python
   fallback ``kernel_python`` (these two on one sensor's rows, or a part of them), and a
   plain Mahony complementary filter compiled with numba in this file as the ceiling of a
   per-sample loop.
   Target: at least 5 million rows/s.
3. Streaming: 10 rows of one sensor, ``feed`` + ``poll``, in a live pipeline past
   calibration, the sensors' chunks in turn. Target: under 50 µs. The pipeline's age (how
   much it holds already) is varied, since a poll may cost more in a longer session.

The recording is simulated (``long_session``: calibration poses, then sets of elbow
flexion, pronation and wrist flexion with rests): 17 sets cut at 30:00; ``--quick`` tiles
the 7-minute 4-set session with shifted times instead and repeats less.

One core: every thread pool is set to one thread before numpy is imported
(OMP/OpenBLAS/MKL/numba), and the process is pinned to one CPU (``--cpu``, default the
last one allowed). Times are medians of several runs after a warm-up run, in one process;
rivals run in turn (one run of each, then again) so that a change in the machine's speed
hits them alike; other work on the machine still shows in them. numba's compile (or cache
load) time is reported apart. vqf and imufusion are optional bench dependencies (the
``bench`` extra); without them their rows are skipped. Results are also written to
``bench/results/speed.csv``.
"""

from __future__ import annotations

import os

# One thread in every pool, set before numpy (and its BLAS) is imported.
os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import cProfile
import csv
import functools
import gc
import math
import platform
import pstats
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, replace
from importlib import metadata
from pathlib import Path

import numba
import numpy as np
from armtrack.estimator.arm import inverse as inverse_module
from armtrack.estimator.orientation import qcf as qcf_module
from armtrack.estimator.orientation import qcf_kernel
from armtrack.estimator.orientation.qcf import QuaternionComplementaryFilter
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, estimate_recording
from armtrack.estimator.pipeline import calibrate as calibrate_module
from armtrack.estimator.pipeline import session as session_module
from armtrack.estimator.pipeline import tracks as tracks_module
from armtrack.estimator.recording import Recording, SensorStream
from armtrack.estimator.simulation import SimulationConfig, simulate

RATE_HZ = 100.0
MINUTES = 30
ROWS_PER_SENSOR = int(MINUTES * 60 * RATE_HZ)  # 180,000; 540,000 for the three sensors
#: long_session: 11 s of calibration, then sets of 107.4 s; 17 sets reach 30:37.
LONG_SETS = 17
SEED = 1
CHUNK_ROWS = 10

TARGET_BATCH_S = 0.5
TARGET_QCF_ROWS_PER_S = 5e6
TARGET_CHUNK_S = 50e-6

RESULTS = Path(__file__).resolve().parent / "results" / "speed.csv"
REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Plan:
    """How much to run: the full benchmark or ``--quick``."""

    quick: bool
    batch_repeat: int
    filter_repeat: int
    vqf_repeat: int
    imufusion_rows: int
    imufusion_repeat: int
    python_rows: int
    python_repeat: int
    stream_ages_s: tuple[float, ...]
    stream_rounds: int
    stream_warmup: int

    @staticmethod
    def make(quick: bool) -> Plan:
        if quick:
            return Plan(True, 3, 3, 2, 30_000, 1, 5_000, 1, (60.0, 1740.0), 200, 20)
        return Plan(False, 7, 7, 5, 180_000, 3, 20_000, 3, (60.0, 600.0, 1740.0), 600, 50)


@dataclass
class Timing:
    """Wall times [s] of the measured runs (warm-up excluded)."""

    times: list[float]

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    @property
    def spread(self) -> str:
        return f"{min(self.times):.3f}–{max(self.times):.3f}"


@dataclass
class Result:
    """One line of ``speed.csv``."""

    section: str
    item: str
    rows: int
    seconds: float  # median per run (streaming: per chunk)
    rows_per_s: float | None = None
    ratio: float | None = None  # see the section's table for what it is relative to
    p99_s: float | None = None
    target: str = ""
    met: str = ""
    note: str = ""


# -- the recording ---------------------------------------------------------------------------
def make_recording(quick: bool) -> tuple[Recording, str]:
    """A 30-minute, 3-sensor, 9-axis, 100 Hz recording: 180,000 rows per sensor."""
    if quick:
        sim = simulate(SimulationConfig(exercise="long_session", seed=SEED))
    else:
        sim = simulate(SimulationConfig(exercise="long_session", repetitions=LONG_SETS,
                                        seed=SEED))
    source = sim.recording
    n_source = min(len(s.t) for s in source.sensors.values())
    index = np.arange(ROWS_PER_SENSOR) % n_source  # tiles a shorter session end to end
    t = np.arange(ROWS_PER_SENSOR) / RATE_HZ  # the simulator's grid (no jitter, no loss)
    sensors = {name: SensorStream(t, s.acc[index], s.gyr[index], s.mag[index])
               for name, s in source.sensors.items()}
    if n_source >= ROWS_PER_SENSOR:
        how = f"long_session, {LONG_SETS} sets simulated, cut at {MINUTES}:00"
    else:
        how = (f"long_session ({n_source / RATE_HZ / 60:.1f} min) tiled "
               f"{ROWS_PER_SENSOR / n_source:.2f}x with shifted times")
    recording = replace(source, sensors=sensors,
                        metadata={**source.metadata, "scenario": "bench-speed"})
    return recording, how


def sensor_rows(recording: Recording):
    return [(s.t, s.acc, s.gyr, s.mag) for s in recording.sensors.values()]


# -- 1. batch --------------------------------------------------------------------------------
class StageTimer:
    """Exclusive wall time per stage, from wrappers put around the estimator's functions
    for the length of a ``with`` block (and taken off after it)."""

    def __init__(self, targets):
        self.targets = targets
        self.totals: dict[str, float] = defaultdict(float)
        self._stack: list[float] = []
        self._saved: list[tuple[object, str, object]] = []

    def _wrap(self, fn, label):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            self._stack.append(0.0)  # time spent in stages nested in this one
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - start
                nested = self._stack.pop()
                self.totals[label] += elapsed - nested
                if self._stack:
                    self._stack[-1] += elapsed
        return wrapper

    def __enter__(self) -> StageTimer:
        for owner, name, label in self.targets:
            original = getattr(owner, name)
            self._saved.append((owner, name, original))
            setattr(owner, name, self._wrap(original, label))
        return self

    def __exit__(self, *exc) -> None:
        for owner, name, original in reversed(self._saved):
            setattr(owner, name, original)
        self._saved.clear()


#: (owner, attribute, label, group): the stages of ``Pipeline``, in the order they run.
STAGES = [
    (qcf_module.QuaternionComplementaryFilter, "update", "qcf filter (numba kernel + checks)",
     "filters"),
    (tracks_module.SensorTrack, "append", "feed bookkeeping (SensorTrack.append)", "filters"),
    (tracks_module.SensorTrack, "arrays", "joining chunks (SensorTrack.arrays)", "other"),
    (session_module, "calibrate", "calibration", "calibration"),
    (session_module, "_orientation_at", "slerp to the reference times", "slerp/joint angles"),
    (tracks_module.SensorTrack, "orientation_at", "slerp to the reference times",
     "slerp/joint angles"),
    (tracks_module.SensorTrack, "discard_before", "forgetting old rows (discard_before)",
     "other"),
    (session_module, "quat_to_matrix", "quaternion -> matrix (scipy)", "slerp/joint angles"),
    (calibrate_module.Calibration, "R_world_segment", "sensor -> segment rotations",
     "slerp/joint angles"),
    (inverse_module.JointAngleSolver, "update", "joint angles (inverse kinematics)",
     "slerp/joint angles"),
    (session_module.Pipeline, "_apply_constraints", "heading constraints (compiled)",
     "slerp/joint angles"),
    (session_module, "forward_kinematics", "forward kinematics", "forward kinematics"),
]
REST_LABEL = "rest of Pipeline._estimate (thorax @ FK rotations, Estimates)"
REST_GROUP = "forward kinematics"


def stage_targets():
    """The stages this version of the estimator has (it changes under the bench)."""
    return [(owner, name, label) for owner, name, label, _ in STAGES if hasattr(owner, name)]


def batch_breakdown(recording: Recording, repeat: int) -> tuple[dict[str, float], float]:
    """Median exclusive seconds per stage over ``repeat`` instrumented runs, and the
    median instrumented total."""
    per_stage: dict[str, list[float]] = defaultdict(list)
    totals = []
    for _ in range(repeat):
        gc.collect()
        with StageTimer(stage_targets()) as timer:
            start = time.perf_counter()
            estimate_recording(recording)
            total = time.perf_counter() - start
        totals.append(total)
        for _, _, label in stage_targets():
            per_stage[label].append(timer.totals.get(label, 0.0))
        per_stage[REST_LABEL].append(total - sum(timer.totals.values()))
    return {k: statistics.median(v) for k, v in per_stage.items()}, statistics.median(totals)


def profile_top(fn, count: int) -> list[tuple[str, int, float, float]]:
    """The ``count`` functions with the most own time: (where, calls, own s, cumulative s)."""
    profiler = cProfile.Profile()
    gc.collect()
    profiler.enable()
    fn()
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.items():
        path = Path(filename)
        try:
            where = f"{path.resolve().relative_to(REPO)}:{line}({name})"
        except ValueError:
            where = f"{path.name}:{line}({name})" if line else name
        rows.append((where, calls, own, cumulative))
    rows.sort(key=lambda r: r[2], reverse=True)
    return rows[:count]


# -- 2. the filter alone -----------------------------------------------------------------------
def plain_cf(t, acc, gyr, gain, out_q):
    """Mahony's proportional complementary filter and nothing else (6-axis, no bias, no
    rest, no magnetometer): the ceiling of a compiled per-sample loop."""
    qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
    t_last = t[0]
    for i in range(t.shape[0]):
        dt = t[i] - t_last
        t_last = t[i]
        wx, wy, wz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        if norm > 0.0:
            ax, ay, az = ax / norm, ay / norm, az / norm
            # the world's up in the sensor frame: the third row of R(q)
            vx = 2.0 * (qx * qz - qw * qy)
            vy = 2.0 * (qw * qx + qy * qz)
            vz = qw * qw - qx * qx - qy * qy + qz * qz
            wx += gain * (ay * vz - az * vy)
            wy += gain * (az * vx - ax * vz)
            wz += gain * (ax * vy - ay * vx)
        hx, hy, hz = 0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz
        qw, qx, qy, qz = (qw - qx * hx - qy * hy - qz * hz,
                          qx + qw * hx + qy * hz - qz * hy,
                          qy + qw * hy - qx * hz + qz * hx,
                          qz + qw * hz + qx * hy - qy * hx)
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
        out_q[i, 0], out_q[i, 1], out_q[i, 2], out_q[i, 3] = qw, qx, qy, qz


plain_cf_compiled = numba.njit(cache=False, nogil=True)(plain_cf)


def first_call_seconds(kernel) -> float:
    """Seconds of a kernel's first call on two rows (its compile, or its cache load)."""
    t = np.array([0.0, 0.01])
    acc = np.array([[0.0, 0.0, 9.81]] * 2)
    gyr = np.zeros((2, 3))
    mag = np.array([[20.0, 0.0, -40.0]] * 2)
    params = qcf_module.QcfParams().as_array()
    state = np.zeros(qcf_kernel.STATE_SIZE)
    outputs = (np.empty((2, 4)), np.empty((2, 3)), np.zeros(2, np.bool_), np.zeros(2, np.bool_))
    start = time.perf_counter()
    kernel(t, acc, gyr, mag, 1, params, state, *outputs)
    return time.perf_counter() - start


def compile_times() -> list[Result]:
    """numba's one-off costs, before anything else calls the kernels."""
    results = []
    seconds = first_call_seconds(qcf_kernel.kernel)
    stats = qcf_kernel.kernel.stats
    how = ("loaded from numba's on-disk cache" if stats.cache_hits else
           "compiled (no usable cache entry); cached for the next process")
    results.append(Result("compile", "qcf kernel: first call in this process", 0, seconds,
                          note=how))
    fresh = numba.njit(cache=False, nogil=True)(qcf_kernel.kernel_python)
    results.append(Result("compile", "qcf kernel: compile without a cache", 0,
                          first_call_seconds(fresh),
                          note="a fresh install, or a read-only install folder"))
    t = np.array([0.0, 0.01])
    start = time.perf_counter()
    plain_cf_compiled(t, np.ones((2, 3)), np.zeros((2, 3)), 1.0, np.empty((2, 4)))
    results.append(Result("compile", "plain numba CF (ceiling): compile", 0,
                          time.perf_counter() - start))
    return results


@dataclass
class Candidate:
    """One contender of a side-by-side comparison."""

    item: str
    fn: object
    rows: int
    repeat: int
    note: str


def interleaved(candidates: list[Candidate]) -> dict[str, Timing]:
    """Each candidate's timing, the runs taken in turn (one run of each, then again) so
    that a change in the machine's speed while they run hits them all alike; one warm-up
    run each first."""
    for c in candidates:
        c.fn()
    times: dict[str, list[float]] = {c.item: [] for c in candidates}
    for round_ in range(max(c.repeat for c in candidates)):
        for c in candidates:
            if round_ < c.repeat:
                gc.collect()
                start = time.perf_counter()
                c.fn()
                times[c.item].append(time.perf_counter() - start)
    return {item: Timing(t) for item, t in times.items()}


def filter_results(recording: Recording, plan: Plan) -> list[Result]:
    rows = sensor_rows(recording)
    n_rows = sum(len(t) for t, *_ in rows)
    candidates = []

    def qcf_all():
        return [QuaternionComplementaryFilter().update_batch(t, acc, gyr, mag)
                for t, acc, gyr, mag in rows]

    candidates.append(Candidate("qcf update_batch (numba kernel)", qcf_all, n_rows,
                                plan.filter_repeat, "9-axis, 3 sensors in turn"))

    def plain_all():
        outs = [np.empty((len(t), 4)) for t, *_ in rows]
        for (t, acc, gyr, _), out in zip(rows, outs, strict=True):
            plain_cf_compiled(t, acc, gyr, 1.0, out)
        return outs

    candidates.append(Candidate("plain numba Mahony CF (ceiling)", plain_all, n_rows,
                                plan.filter_repeat, "6-axis, proportional term only, q out only"))

    try:
        from vqf import VQF
    except ImportError:
        print("vqf not installed: pip install vqf (optional bench dependency)")
    else:
        def vqf_all():
            return [VQF(1.0 / RATE_HZ).updateBatch(gyr, acc, mag) for _, acc, gyr, mag in rows]
        candidates.append(Candidate("vqf.VQF(0.01).updateBatch (C++)", vqf_all, n_rows,
                                    plan.vqf_repeat, "9-axis, default options, fixed sample time"))

    try:
        import imufusion
    except ImportError:
        print("imufusion not installed: pip install imufusion (optional bench dependency)")
    else:
        _, acc, gyr, mag = rows[0]
        n_fusion = plan.imufusion_rows
        gyr_deg = np.ascontiguousarray(np.rad2deg(gyr[:n_fusion]))  # its units: deg/s and g
        acc_g = np.ascontiguousarray(acc[:n_fusion] / 9.80665)
        mag_n = np.ascontiguousarray(mag[:n_fusion])

        def imufusion_loop():
            ahrs = imufusion.Ahrs()
            ahrs.set_settings(imufusion.AhrsSettings(sample_rate=RATE_HZ))
            q = np.empty((n_fusion, 4))
            for i, (g, a, m) in enumerate(zip(gyr_deg, acc_g, mag_n, strict=True)):
                ahrs.update(g, a, m)
                q[i] = ahrs.get_quaternion()
            return q

        candidates.append(Candidate(
            "imufusion.Ahrs update per sample (C, Python loop)", imufusion_loop, n_fusion,
            plan.imufusion_repeat,
            f"9-axis; {n_fusion:,} rows of one sensor, units converted beforehand"))

    t, acc, gyr, mag = rows[0]
    n = plan.python_rows

    def python_fallback():
        return QuaternionComplementaryFilter(compiled=False).update_batch(
            t[:n], acc[:n], gyr[:n], mag[:n])

    candidates.append(Candidate("qcf kernel_python (pure-Python fallback)", python_fallback, n,
                                plan.python_repeat, f"9-axis; {n:,} rows of one sensor"))

    timings = interleaved(candidates)
    qcf_rate = n_rows / timings[candidates[0].item].median
    results = []
    for c in candidates:
        timing = timings[c.item]
        rate = c.rows / timing.median
        result = Result("filter", c.item, c.rows, timing.median, rate, qcf_rate / rate,
                        note=f"{c.note}; median of {len(timing.times)}, "
                             f"range {timing.spread} s")
        if c is candidates[0]:
            result.target = f">= {TARGET_QCF_ROWS_PER_S / 1e6:.0f} M rows/s"
            result.met = "yes" if rate >= TARGET_QCF_ROWS_PER_S else "no"
        results.append(result)
    return results


# -- 3. streaming ----------------------------------------------------------------------------
@dataclass
class StreamCosts:
    age_s: float
    feed: np.ndarray  # seconds per chunk
    poll: np.ndarray
    produced: np.ndarray  # estimates the poll gave
    estimates: int


def live_pipeline(recording: Recording, age_s: float) -> tuple[Pipeline, int]:
    """A pipeline fed the first ``age_s`` seconds of every sensor in one go and polled
    (calibrated, every estimate so far taken), and the next row to feed."""
    config = PipelineConfig(side=recording.side, lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors), filter="qcf")
    pipeline = Pipeline(config, poses=recording.calibration)
    start = round(age_s * RATE_HZ)
    for name, s in recording.sensors.items():
        pipeline.feed(name, s.t[:start], s.acc[:start], s.gyr[:start], s.mag[:start])
    pipeline.poll()
    assert pipeline.calibration is not None, "the pipeline should be past calibration"
    return pipeline, start


def stream(recording: Recording, age_s: float, rounds: int, warmup: int,
           timer: StageTimer | None = None) -> StreamCosts:
    """``rounds`` rounds of one 10-row chunk per sensor, each fed then polled at once;
    the first ``warmup`` rounds are not kept."""
    pipeline, start = live_pipeline(recording, age_s)
    streams = list(recording.sensors.items())
    feed, poll, produced = [], [], []
    clock = time.perf_counter
    if timer is not None:
        timer.__enter__()
    try:
        for r in range(rounds):
            a = start + r * CHUNK_ROWS
            b = a + CHUNK_ROWS
            if r == warmup and timer is not None:
                timer.totals.clear()
            for name, s in streams:
                t, acc, gyr, mag = s.t[a:b], s.acc[a:b], s.gyr[a:b], s.mag[a:b]
                t0 = clock()
                pipeline.feed(name, t, acc, gyr, mag)
                t1 = clock()
                estimates = pipeline.poll()
                t2 = clock()
                if r >= warmup:
                    feed.append(t1 - t0)
                    poll.append(t2 - t1)
                    produced.append(len(estimates))
    finally:
        if timer is not None:
            timer.__exit__(None, None, None)
    return StreamCosts(age_s, np.array(feed), np.array(poll), np.array(produced),
                       int(sum(produced)))


# -- output ------------------------------------------------------------------------------------
def machine_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores"


def versions() -> str:
    parts = [f"python {sys.version.split()[0]}", f"numpy {np.__version__}",
             f"numba {numba.__version__}"]
    for name in ("scipy", "vqf", "imufusion"):
        try:
            parts.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            parts.append(f"{name} absent")
    return ", ".join(parts)


def code_version() -> str:
    """The commit measured, and the estimator's files that differ from it."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True,
                                  text=True, timeout=10, check=True).stdout.rstrip()
        except (OSError, subprocess.SubprocessError):
            return ""
    commit = git("rev-parse", "--short", "HEAD").strip() or "unknown"
    changed = [line[3:] for line in git("status", "--porcelain", "--", "estimator").splitlines()]
    return commit + (f" + uncommitted changes in {', '.join(changed)}" if changed else " (clean)")


def blas_line() -> str:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return "thread pools: threadpoolctl absent (pip install threadpoolctl to list them)"
    pools = [f"{p['internal_api']} {p.get('architecture', '')} x{p['num_threads']}".strip()
             for p in threadpool_info()]
    return "thread pools: " + (", ".join(pools) or "none loaded")


def fmt_rate(rate: float | None) -> str:
    return "" if rate is None else f"{rate / 1e6:8.2f} M"


def us(seconds: float) -> str:
    return f"{seconds * 1e6:8.1f}"


def write_csv(results: list[Result], mode: str, version: str) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with open(RESULTS, "w", encoding="utf-8", newline="") as file:
        writer = csv.writer(file, lineterminator="\n")
        writer.writerow(["mode", "commit", "section", "item", "rows", "seconds", "rows_per_s",
                         "ratio", "p99_seconds", "target", "met", "note"])
        for r in results:
            writer.writerow([mode, version, r.section, r.item, r.rows, f"{r.seconds:.6g}",
                             "" if r.rows_per_s is None else f"{r.rows_per_s:.0f}",
                             "" if r.ratio is None else f"{r.ratio:.3f}",
                             "" if r.p99_s is None else f"{r.p99_s:.6g}",
                             r.target, r.met, r.note])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="a tiled 7-minute session and fewer repeats (about half a minute)")
    parser.add_argument("--cpu", type=int, default=None,
                        help="the CPU to pin to (default: the last one allowed)")
    parser.add_argument("--no-pin", action="store_true", help="do not pin to one CPU")
    args = parser.parse_args(argv)
    plan = Plan.make(args.quick)
    mode = "quick" if plan.quick else "full"

    pinned = "not pinned"
    if not args.no_pin and hasattr(os, "sched_setaffinity"):
        cpu = args.cpu if args.cpu is not None else max(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        pinned = f"pinned to CPU {cpu}"
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    print(f"machine: {machine_line()}; {pinned}; OMP/OPENBLAS/MKL/NUMBA_NUM_THREADS=1; "
          f"load average {load} (other work on the machine shows in the times)")
    if hasattr(os, "getloadavg") and os.getloadavg()[0] > 0.5:
        print("warning: the machine is busy (load average above 0.5 before this bench "
              "started): expect slower times and a long tail")
    version = code_version()
    print(f"estimator: commit {version}")
    print(versions())
    print(blas_line())
    results: list[Result] = []

    # numba's one-off cost first, before anything calls the kernels.
    compiles = compile_times()
    results += compiles

    start = time.perf_counter()
    recording, how = make_recording(plan.quick)
    rows = sum(len(s.t) for s in recording.sensors.values())
    print(f"recording: {len(recording.sensors)} sensors x {ROWS_PER_SENSOR:,} rows = "
          f"{rows:,} rows ({MINUTES} min at {RATE_HZ:.0f} Hz, 9-axis), {how}; "
          f"simulated in {time.perf_counter() - start:.1f} s (not measured); mode {mode}")

    # -- 1. batch --
    print("\n1. Batch: estimate_recording on the whole recording (reading excluded)")
    six_axis = replace(recording, sensors={n: SensorStream(s.t, s.acc, s.gyr, None)
                                           for n, s in recording.sensors.items()})
    first = time.perf_counter()
    estimates, _ = estimate_recording(recording)
    first = time.perf_counter() - first
    nine_item, six_item = "estimate_recording (whole pipeline)", "estimate_recording, 6-axis"
    timings = interleaved([
        Candidate(nine_item, lambda: estimate_recording(recording), rows, plan.batch_repeat, ""),
        Candidate(six_item, lambda: estimate_recording(six_axis), rows, plan.batch_repeat, ""),
    ])
    timing, six = timings[nine_item], timings[six_item]
    met = timing.median < TARGET_BATCH_S
    results.append(Result("batch", nine_item, rows, timing.median,
                          rows / timing.median, timing.median / TARGET_BATCH_S,
                          target=f"< {TARGET_BATCH_S} s", met="yes" if met else "no",
                          note=f"median of {plan.batch_repeat}, range {timing.spread} s; "
                               f"{len(estimates):,} estimates; ratio = vs target"))
    results.append(Result("batch", "estimate_recording: first run (warm-up)", rows, first,
                          note="not in the median"))
    results.append(Result("batch-6axis", "estimate_recording, 6-axis (mag left out)", rows,
                          six.median, rows / six.median, six.median / timing.median,
                          note=f"ratio = vs 9-axis; range {six.spread} s; "
                               f"with the 6-axis heading constraints"))
    stages, instrumented = batch_breakdown(recording, plan.batch_repeat)
    print(f"{'':<4}{'seconds':>8} {'vs target':>9} {'rows/s':>10}  note")
    print(f"{'':<4}{timing.median:8.3f} {timing.median / TARGET_BATCH_S:8.2f}x "
          f"{fmt_rate(rows / timing.median)}  median of {plan.batch_repeat} "
          f"(range {timing.spread} s), target < {TARGET_BATCH_S} s: "
          f"{'met' if met else f'missed by {timing.median - TARGET_BATCH_S:.3f} s'}")
    print(f"{'':<4}{first:8.3f}{'':>21}  first run (warm-up, not in the median)")
    print(f"{'':<4}{six.median:8.3f} {six.median / TARGET_BATCH_S:8.2f}x "
          f"{fmt_rate(rows / six.median)}  the same rows as a 6-axis kit (mag left out: "
          f"heading constraints on), {six.median / timing.median:.2f}x the 9-axis time")

    print(f"\n   where the time goes (exclusive, median of {plan.batch_repeat} instrumented "
          f"runs; their total {instrumented:.3f} s)")
    print(f"   {'stage':<62} {'group':<19} {'seconds':>8} {'share':>6}")
    groups: dict[str, float] = defaultdict(float)
    group_of = {label: group for _, _, label, group in STAGES} | {REST_LABEL: REST_GROUP}
    for label, seconds in sorted(stages.items(), key=lambda kv: -kv[1]):
        if seconds == 0.0:
            continue  # a stage this recording does not use (6-axis constraints)
        group = group_of[label]
        groups[group] += seconds
        print(f"   {label:<62} {group:<19} {seconds:8.3f} {seconds / instrumented:6.1%}")
        results.append(Result("batch-stage", label, rows, seconds,
                              rows / seconds if seconds > 0 else None,
                              seconds / instrumented, note=f"group: {group}; ratio = share"))
    print(f"   {'by group:':<62}")
    for group, seconds in sorted(groups.items(), key=lambda kv: -kv[1]):
        print(f"   {'  ' + group:<62} {'':<19} {seconds:8.3f} {seconds / instrumented:6.1%}")
        results.append(Result("batch-group", group, rows, seconds,
                              rows / seconds if seconds > 0 else None,
                              seconds / instrumented, note="ratio = share"))

    top = profile_top(lambda: estimate_recording(recording), 12)
    print("\n   the profiler's busiest functions (own time; the profiler adds a little)")
    print(f"   {'function':<70} {'calls':>6} {'own s':>7} {'cum s':>7}")
    for where, calls, own, cumulative in top:
        print(f"   {where[:70]:<70} {calls:6d} {own:7.3f} {cumulative:7.3f}")

    # -- 2. the filter alone --
    print(f"\n2. The orientation filter alone on the same {rows:,} rows")
    filters = filter_results(recording, plan)
    results += filters
    print(f"   {'filter':<52} {'rows timed':>10} {'seconds':>8} {'rows/s':>10} "
          f"{'x qcf time':>10}  note")
    for r in filters:
        print(f"   {r.item:<52} {r.rows:10,} {r.seconds:8.4f} {fmt_rate(r.rows_per_s)} "
              f"{r.ratio:9.2f}x  {r.note}")
    print("   (x qcf time: time per row relative to qcf's; below 1 is faster. Subsets are "
          "timed on their rows only; rows/s is comparable.)")
    print("\n   numba one-off costs (not in any median)")
    for r in compiles:
        print(f"   {r.item:<52} {r.seconds:8.3f} s  {r.note}")

    # -- 3. streaming --
    print(f"\n3. Streaming: {CHUNK_ROWS} rows of one sensor, feed + poll, sensors in turn, "
          f"{plan.stream_rounds - plan.stream_warmup} rounds after {plan.stream_warmup} "
          f"of warm-up.\n   Two polls in three give nothing yet; the one after the round's "
          f"last sensor gives {CHUNK_ROWS} estimates ('with estimates'). Target met if the "
          f"median and the p99 are under {TARGET_CHUNK_S * 1e6:.0f} µs.")
    print(f"   {'age':<7} {'chunks':>6} {'feed':>7} {'poll':>7} {'median':>7} {'mean':>7} "
          f"{'p99':>7} | {'with estimates: median':>22} {'p99':>7} | {'p99/target':>10}")
    for age in plan.stream_ages_s:
        costs = stream(recording, age, plan.stream_rounds, plan.stream_warmup)
        total = costs.feed + costs.poll
        median, p99 = float(np.median(total)), float(np.percentile(total, 99))
        mean = float(total.mean())
        with_estimates = total[costs.produced > 0]
        est_median = float(np.median(with_estimates)) if len(with_estimates) else math.nan
        est_p99 = float(np.percentile(with_estimates, 99)) if len(with_estimates) else math.nan
        met = median < TARGET_CHUNK_S and p99 < TARGET_CHUNK_S
        label = f"{age / 60:.0f} min"
        print(f"   {label:<7} {len(total):6d} {us(np.median(costs.feed)):>7} "
              f"{us(np.median(costs.poll)):>7} {us(median):>7} {us(mean):>7} {us(p99):>7} | "
              f"{us(est_median):>22} {us(est_p99):>7} | {p99 / TARGET_CHUNK_S:9.1f}x")
        results.append(Result(
            "stream", f"feed+poll of {CHUNK_ROWS} rows at {label}", CHUNK_ROWS, median,
            CHUNK_ROWS / median, p99 / TARGET_CHUNK_S, p99,
            target=f"< {TARGET_CHUNK_S * 1e6:.0f} µs", met="yes" if met else "no",
            note=f"{len(total)} chunks; ratio = p99/target; mean {mean * 1e6:.1f} µs; feed "
                 f"median {np.median(costs.feed) * 1e6:.1f} µs, poll median "
                 f"{np.median(costs.poll) * 1e6:.1f} µs; chunks with estimates: median "
                 f"{est_median * 1e6:.1f} µs, p99 {est_p99 * 1e6:.1f} µs"))
    print("   [µs per chunk]")

    for age in (plan.stream_ages_s[0], plan.stream_ages_s[-1]):
        timer = StageTimer(stage_targets())
        costs = stream(recording, age, plan.stream_rounds, plan.stream_warmup, timer)
        chunks = len(costs.feed)
        measured = float((costs.feed + costs.poll).sum())
        print(f"\n   where a chunk's time goes at {age / 60:.0f} min (exclusive, mean µs per "
              f"chunk over {chunks} instrumented chunks; their mean "
              f"{measured / chunks * 1e6:.1f} µs)")
        rest = measured - sum(timer.totals.values())
        stream_stages = dict(timer.totals) | {"rest (feed/poll/_advance/_estimate own code)": rest}
        for label, seconds in sorted(stream_stages.items(), key=lambda kv: -kv[1]):
            print(f"   {label:<62} {seconds / chunks * 1e6:8.1f} {seconds / measured:6.1%}")
            results.append(Result("stream-stage", f"{label} at {age / 60:.0f} min", CHUNK_ROWS,
                                  seconds / chunks, ratio=seconds / measured,
                                  note="mean per chunk; ratio = share"))

    # -- summary --
    print("\ntargets")
    for r in results:
        if r.target:
            value = (f"median {r.seconds:.3f} s" if r.section == "batch" else
                     f"{r.rows_per_s / 1e6:.2f} M rows/s" if r.section == "filter" else
                     f"median {r.seconds * 1e6:.0f} µs, p99 {(r.p99_s or 0) * 1e6:.0f} µs")
            print(f"   {r.met:<4} {r.item:<45} {value:<34} target {r.target}")
    write_csv(results, mode, version)
    print(f"\nwritten: {RESULTS.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
