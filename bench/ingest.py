"""Benchmark: how many patients one server takes at once. Run by hand:
``python bench/ingest.py --patients 50 200`` or ``python bench/ingest.py --find-max``.
Not a test.

For each N: a fresh ``armtrack serve`` subprocess on loopback (its own temporary data
folder, SQLite), a therapist (``armtrack create-user``), N patients each with a device
(REST), then one client process that plays N sensor kits (``KitEmulator``: 3 sensors,
9-axis, 100 Hz, 10 rows a message, real-time pace) and holds one ``/ws/live`` viewer per
patient. The exercise is simulated once (``--duration`` seconds of ``elbow_flexion`` with
its calibration poses) and the same recording is played by every kit; the kits' starts are
spread evenly over ``--stagger`` seconds. Before the measured kits, one warm-up kit plays
the recording as fast as it can (numba's caches, the first SQLite pages), not counted.

Measured, per N:

* samples/s stored: sample rows stored (each session's ``samples`` from the REST API after
  the run) over the time from the first kit's ``ready`` to the last kit's ``bye``; and
  loss = rows sent − rows stored (must be 0), every message acked;
* ack latency p50/p99: the kit's send → the ``ack`` covering it (``KitStats``); it holds
  the group commit's wait (``ARMTRACK_ACK_INTERVAL_S``, 0.1 s by default) by design;
* pose latency p50/p99: the server's own ``latency_s`` of every ``pose`` update (newest
  sample's arrival → publication); it starts when the server *reads* the message, so time
  spent in socket buffers while the event loop is busy is not in it;
* pose age p50/p99, measured by the viewer: arrival of a pose at the viewer − the moment
  its newest sample (``t``) was due to be sent by its kit. It holds what ``latency_s``
  leaves out (the kit's lateness, loopback, the server's queue before reading, sending
  the pose), plus how far the estimator's newest estimate trails the newest sample;
* poses/s per viewer (the server publishes at most ``ARMTRACK_LIVE_POSES_HZ``, 30);
* server CPU % (user + system of the server process and its threads, and of its live
  estimation process, 100 % = one core; the notes give the two parts)
  and RSS (the largest seen, and the kernel's peak ``VmHWM``), over the steady window
  (every kit streaming: from the last start + 1 s to the first kit's end), from ``/proc``;
* the client's CPU % over the same window, to show it was not the bottleneck (above
  ~90 % of its core, the numbers say more about the client than about the server);
* errors: ``error`` messages, refused messages, reconnects, kits or viewers that failed;
* in the notes: where the poses over ``--limit-ms`` fell (while kits were starting, all
  streaming, or sessions ending; and the worst second), and the WebSocket extensions the
  server took in the viewers' handshakes.

A run "holds" with zero loss and no errors, every kit done, and pose latency p99 under
``--limit-ms`` (100). ``--find-max`` doubles N from ``--start`` until a run does not hold,
then bisects down to ``--resolution``, and reports the largest N that held.

CPUs: nothing is pinned by default: the server is two processes (the server and its live
estimation process, ``ARMTRACK_LIVE_PROCESSES``), and they and the client share the
machine's cores as the operating system sees fit, as they would on a clinic's server.
``--pin`` pins the server with its live estimation process to one CPU and the client
(with this script and py-spy) to another (or ``--server-cpu``, ``--client-cpu``): a
one-core server. Other work on the machine shows in the numbers; the load average is
printed with every run.

``--instances N`` (default 1) runs N server instances as one clinic network would
(README "Scaling out"): one PostgreSQL database (a fresh database per run on
``--database-url``, default ``ARMTRACK_TEST_POSTGRES_URL``: ``eval "$(.ci/postgres
start)"``), one ``redis-server`` broker that this script starts on a free loopback port,
kit i streaming into instance i mod N and its viewer watching from instance i+1 mod N, so
every pose crosses the broker. The server CPU is then the sum over the instances; pin
nothing on a 2-core box (``--no-pin``): the instances, PostgreSQL, Redis and the client
share its two cores. ``--database-url`` with one instance measures one instance on
PostgreSQL (no broker).

``--profile`` samples the server with py-spy (``pip install py-spy``) through the steady
window of each run and prints where its CPU time goes (own and inclusive time per
function, % of samples). Results are appended to ``bench/results/ingest.csv`` (one row a
run; ``--fresh-csv`` to start the file again).
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import functools
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from array import array
from collections import Counter
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # numpy is imported where it is used: the client process starts lean
    import numpy as np

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "bench" / "results" / "ingest.csv"
PASSWORD = "bench-password-not-secret"
THERAPIST = "bench"
TICKS = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")


# -- small helpers --------------------------------------------------------------------------
def load_average() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def raise_fd_limit() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


def pin(cpu: int | None) -> None:
    if cpu is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {cpu})


def proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process and all its threads (``/proc/PID/stat``)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime (fields 14, 15)


def live_processes(pid: int) -> list[int]:
    """The live estimation processes of server ``pid`` (its multiprocessing children)."""
    children = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            children += [int(c) for c in (task / "children").read_text().split()]
        return [c for c in children
                if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
    except OSError:
        return []


def proc_rss(pid: int) -> tuple[int | None, int | None]:
    """(VmRSS, VmHWM) in bytes."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return None, None
    found = {}
    for line in lines:
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            found[key] = int(value.split()[0]) * 1024
    return found.get("VmRSS"), found.get("VmHWM")


class Sampler(threading.Thread):
    """Samples a process's CPU seconds and RSS every ``interval`` s (monotonic clock,
    the same in every process on Linux)."""

    def __init__(self, pid: int, interval: float = 0.25):
        super().__init__(daemon=True)
        self.pid, self.interval = pid, interval
        self.samples: list[tuple[float, float, int]] = []  # (monotonic, cpu s, rss B)
        self.live: list[float] = []  # cpu s of the live estimation processes, alike
        self.hwm = 0
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            cpu, (rss, hwm) = proc_cpu_s(self.pid), proc_rss(self.pid)
            live = sum(proc_cpu_s(child) or 0.0 for child in live_processes(self.pid))
            if cpu is not None and rss is not None:
                self.samples.append((time.monotonic(), cpu + live, rss))
                self.live.append(live)
                self.hwm = max(self.hwm, hwm or 0)
            self._halt.wait(self.interval)

    def stop(self) -> None:
        self._halt.set()
        self.join()

    def window(self, start: float, end: float) -> tuple[float, int]:
        """CPU % (100 = one core; the process and its live estimation processes) and the
        largest RSS [B] (of the process) between two monotonic times."""
        inside = [s for s in self.samples if start <= s[0] <= end]
        if len(inside) < 2:
            return math.nan, max((s[2] for s in self.samples), default=0)
        (t0, c0, _), (t1, c1, _) = inside[0], inside[-1]
        return 100.0 * (c1 - c0) / (t1 - t0), max(s[2] for s in inside)

    def live_window(self, start: float, end: float) -> float:
        """CPU % of the live estimation processes alone, as ``window``."""
        inside = [(s[0], live) for s, live in zip(self.samples, self.live, strict=True)
                  if start <= s[0] <= end]
        if len(inside) < 2:
            return math.nan
        (t0, c0), (t1, c1) = inside[0], inside[-1]
        return 100.0 * (c1 - c0) / (t1 - t0)


class Samplers:
    """Several servers' samplers as one: CPU % summed, RSS of the largest."""

    def __init__(self, samplers: list[Sampler]):
        self.samplers = samplers

    def start(self) -> None:
        for s in self.samplers:
            s.start()

    def stop(self) -> None:
        for s in self.samplers:
            if s.is_alive():
                s.stop()

    def is_alive(self) -> bool:
        return any(s.is_alive() for s in self.samplers)

    @property
    def hwm(self) -> int:
        return max(s.hwm for s in self.samplers)

    def window(self, start: float, end: float) -> tuple[float, int]:
        parts = [s.window(start, end) for s in self.samplers]
        return sum(p[0] for p in parts), max(p[1] for p in parts)

    def live_window(self, start: float, end: float) -> float:
        return sum(s.live_window(start, end) for s in self.samplers)


def fresh_database(url: str) -> str:
    """A new PostgreSQL database on the server of ``url``; its URL."""
    import secrets

    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    name = f"armtrack_bench_{secrets.token_hex(6)}"
    engine = create_engine(url, isolation_level="AUTOCOMMIT")
    with engine.connect() as connection:
        connection.execute(text(f"CREATE DATABASE {name}"))
    engine.dispose()
    return make_url(url).set(database=name).render_as_string(hide_password=False)


def start_broker(data_dir: Path) -> tuple[subprocess.Popen, str]:
    """``redis-server`` on a free loopback port (no persistence); the process and URL."""
    import socket

    port = free_port()
    process = subprocess.Popen(["redis-server", "--port", str(port), "--bind", "127.0.0.1",
                                "--save", "", "--appendonly", "no", "--dir", str(data_dir)],
                               stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return process, f"redis://127.0.0.1:{port}/0"
        time.sleep(0.05)
    process.kill()
    raise RuntimeError("redis-server did not start")


def code_version() -> str:
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True,
                                  text=True, timeout=10, check=True).stdout.rstrip()
        except (OSError, subprocess.SubprocessError):
            return ""
    commit = git("rev-parse", "--short", "HEAD").strip() or "unknown"
    changed = [line[3:] for line in git("status", "--porcelain", "--", "server").splitlines()]
    return commit + (f" + uncommitted changes in {', '.join(changed)}" if changed
                     else " (server clean)")


# -- the client process: N kits and N viewers in one event loop ----------------------------
_POSE_T = re.compile(r'"t":([-0-9.eE+]+)')


def make_cached_plan(recording, rows_per_message: int):
    """The recording's ``MessagePlan`` with every message JSON-encoded once, shared by
    every kit (they all play the same recording), so the client spends its time sending,
    not encoding."""
    from armtrack.server.emulator import MessagePlan

    class CachedPlan(MessagePlan):
        def __init__(self, *args):
            super().__init__(*args)
            self.texts = [super(CachedPlan, self).encode(seq) for seq in range(len(self))]

        def encode(self, seq: int, wire_seq: int | None = None) -> str:
            if wire_seq is None or wire_seq == seq:
                return self.texts[seq]
            return super().encode(seq, wire_seq)  # renumbered (a new session's)

    return CachedPlan(recording, rows_per_message)


@dataclass
class ViewerStats:
    poses: int = 0
    other: int = 0
    error: str = ""
    extensions: str = ""  # negotiated in the handshake (permessage-deflate or none)
    first: float = math.nan
    last: float = math.nan


async def viewer(url: str, token: str, ready: asyncio.Event, done: asyncio.Event,
                 kit, plan, latencies: array, latency_at: array, ages: array,
                 received: array, stats: ViewerStats, deflate: bool) -> None:
    """One therapist's ``/ws/live`` feed: every pose's ``latency_s`` and age, until the
    session is closed (or the kit is done and 5 s passed)."""
    from websockets.asyncio.client import connect

    t0 = plan.start_time
    try:
        async with connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                           open_timeout=60, max_size=2**22,
                           compression="deflate" if deflate else None) as ws:
            stats.extensions = ",".join(e.name for e in ws.protocol.extensions) or "none"
            ready.set()
            deadline = None
            while True:
                timeout = 5.0 if deadline is None else max(deadline - time.monotonic(), 0.0)
                try:
                    async with asyncio.timeout(timeout):
                        text = await ws.recv()
                except TimeoutError:
                    if done.is_set():
                        if deadline is None:
                            deadline = time.monotonic() + 5.0
                            continue
                        break
                    continue
                now = time.monotonic()
                if text.startswith('{"kind":"pose"'):
                    stats.poses += 1
                    if stats.poses == 1:
                        stats.first = now
                    stats.last = now
                    i = text.rfind('"latency_s":')
                    if i >= 0:
                        end = i + 12
                        while text[end] not in ",}":
                            end += 1
                        latencies.append(float(text[i + 12:end]))
                        latency_at.append(now)
                    m = _POSE_T.search(text, 0, 200)
                    started = kit.stats.started
                    if m is not None and started is not None:
                        due = started + (float(m.group(1)) - t0) / kit.speed
                        ages.append(now - due)
                        received.append(now)
                elif '"status":"closed"' in text and '"kind":"session"' in text:
                    break
                else:
                    stats.other += 1
    except Exception as exc:
        stats.error = f"{type(exc).__name__}: {exc}"
        ready.set()


async def client_main(config: dict) -> dict:
    from armtrack.estimator.recording import read_recording
    from armtrack.server.emulator import KitEmulator

    if not config["deflate"]:  # kits and viewers offer no permessage-deflate
        from armtrack.server.emulator import kit as kit_module
        kit_module.connect = functools.partial(kit_module.connect, compression=None)
    recording = read_recording(config["recording"])
    plan = make_cached_plan(recording, config["rows_per_message"])
    ingest_url, live_url = config["ingest_url"], config["live_url"]
    # several instances: kit i into instance i mod N, its viewer on instance i+1 mod N
    ingest_urls, live_urls = config.get("ingest_urls", [ingest_url]), config.get(
        "live_urls", [live_url])

    def kit_for(token: str, speed: float, device: str, url: str = ingest_url) -> KitEmulator:
        kit = KitEmulator(recording, url, token, device=device,
                          rows_per_message=config["rows_per_message"], speed=speed,
                          ack_timeout_s=30.0, open_timeout_s=60.0)
        kit.plan = plan  # the shared, pre-encoded plan (same messages, same times)
        return kit

    # warm-up: one kit as fast as it goes, its session closed before anything is measured
    warm = config["warmup"]
    warm_started = time.monotonic()
    warm_error = ""
    if warm is not None:
        try:
            await kit_for(warm["token"], math.inf, "bench-warmup").run()
        except Exception as exc:
            warm_error = f"{type(exc).__name__}: {exc}"
        await asyncio.sleep(2.0)  # its batch processing after bye
    warm_s = time.monotonic() - warm_started

    patients = config["patients"]
    n = len(patients)
    kits = [kit_for(p["token"], config["speed"], f"bench-kit-{p['patient_id']}",
                    ingest_urls[i % len(ingest_urls)])
            for i, p in enumerate(patients)]
    latencies, latency_at, ages, received = array("d"), array("d"), array("d"), array("d")
    viewers = [ViewerStats() for _ in patients]
    kit_errors: list[str] = [""] * n
    kit_done = [asyncio.Event() for _ in patients]
    starts: list[float] = [math.nan] * n

    # viewers first, all connected before the first kit starts
    viewer_ready = [asyncio.Event() for _ in patients]
    viewer_tasks = [asyncio.create_task(viewer(
        f"{live_urls[(i + 1) % len(live_urls)]}?patient={p['patient_id']}",
        config["therapist_token"], viewer_ready[i],
        kit_done[i], kits[i], plan, latencies, latency_at, ages, received, viewers[i],
        config["deflate"]))
        for i, p in enumerate(patients)]
    for event in viewer_ready:
        await event.wait()

    cpu0 = time.process_time()
    begin = time.monotonic()
    stagger = config["stagger_s"]

    async def play(i: int) -> None:
        await asyncio.sleep(stagger * i / max(n, 1))
        starts[i] = time.monotonic()
        try:
            await kits[i].run()
        except Exception as exc:
            kit_errors[i] = f"{type(exc).__name__}: {exc}"
        finally:
            kit_done[i].set()

    await asyncio.gather(*(play(i) for i in range(n)))
    end_kits = time.monotonic()
    cpu_kits = time.process_time() - cpu0
    await asyncio.gather(*viewer_tasks)

    stats = [k.stats for k in kits]
    ack = array("d")
    for s in stats:
        ack.extend(s.latencies_s)
    readies = [s.started for s in stats if s.started is not None]
    byes = [s.finished for s in stats if s.finished is not None]
    rusage = resource.getrusage(resource.RUSAGE_SELF)
    return {
        "n": n, "warmup_s": warm_s, "warmup_error": warm_error,
        "begin": begin, "end_kits": end_kits, "client_cpu_s": cpu_kits,
        "client_maxrss": rusage.ru_maxrss * 1024,
        "first_start": min(starts) if n else math.nan,
        "last_start": max(starts) if n else math.nan,
        "first_ready": min(readies, default=math.nan),
        "last_bye": max(byes, default=math.nan),
        "first_bye": min(byes, default=math.nan),
        "messages_total": sum(s.total for s in stats),
        "acked": sum(s.acked for s in stats),
        "refused": sum(s.refused for s in stats),
        "errors": sum(len(s.errors) for s in stats),
        "error_examples": [e["reason"] for s in stats for e in s.errors][:5],
        "reconnects": sum(s.reconnects for s in stats),
        "rows_sent": sum(s.rows_sent for s in stats),
        "rows_acked": sum(s.rows_acked for s in stats),
        "rows_planned": plan.total_rows * n,
        "kits_failed": sum(1 for e in kit_errors if e),
        "kit_error_examples": [e for e in kit_errors if e][:5],
        "viewers_failed": sum(1 for v in viewers if v.error),
        "viewer_error_examples": [v.error for v in viewers if v.error][:5],
        "sessions": [s.session for s in stats],
        "poses": sum(v.poses for v in viewers),
        "viewer_extensions": sorted({v.extensions for v in viewers if v.extensions}),
        "pose_rate": [v.poses / (v.last - v.first) if v.poses > 1 else 0.0 for v in viewers],
        "ack_latencies": ack.tobytes().hex(),
        "pose_latencies": latencies.tobytes().hex(),
        "pose_latency_at": latency_at.tobytes().hex(),
        "pose_ages": ages.tobytes().hex(),
        "pose_received": received.tobytes().hex(),
    }


def client_entry(config_path: str, output_path: str) -> int:
    raise_fd_limit()
    config = json.loads(Path(config_path).read_text())
    # uvloop (uvicorn's, so always there) as the server has it: the emulated kits and
    # viewers share this machine with the server, and the standard loop costs them more
    try:
        import uvloop
        run = uvloop.run
    except ImportError:  # pragma: no cover - uvicorn[standard] brings it
        run = asyncio.run
    result = run(client_main(config))
    Path(output_path).write_text(json.dumps(result))
    return 0


# -- the orchestrator ----------------------------------------------------------------------
@dataclass
class Run:
    n: int
    holds: bool = False
    why: str = ""
    load_before: str = ""
    load_after: str = ""
    duration_s: float = 0.0
    rows_planned: int = 0
    rows_sent: int = 0
    rows_acked: int = 0
    rows_stored: int = 0
    loss: int = 0
    samples_per_s: float = math.nan
    messages_per_s: float = math.nan
    ack_p50_ms: float = math.nan
    ack_p99_ms: float = math.nan
    pose_p50_ms: float = math.nan
    pose_p99_ms: float = math.nan
    pose_max_ms: float = math.nan
    age_p50_ms: float = math.nan
    age_p99_ms: float = math.nan
    poses: int = 0
    poses_per_s_viewer: float = math.nan
    server_cpu_pct: float = math.nan
    server_cpu_run_pct: float = math.nan
    server_rss_mb: float = math.nan
    server_hwm_mb: float = math.nan
    client_cpu_pct: float = math.nan
    errors: int = 0
    refused: int = 0
    reconnects: int = 0
    kits_failed: int = 0
    viewers_failed: int = 0
    steady_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    profile: list[tuple[str, float, float]] = field(default_factory=list)


def start_server(data_dir: Path, port: int, cpu: int | None, env_extra: dict[str, str]
                 ) -> subprocess.Popen:
    import httpx

    log = open(data_dir / "server.log", "ab")
    # one bench therapist watches every simulated patient at once, more than a real
    # account's ARMTRACK_MAX_LIVE_FEEDS_PER_USER allows: not bounded here
    env = {"ARMTRACK_MAX_LIVE_FEEDS_PER_USER": "1000000", **os.environ, **env_extra}
    process = subprocess.Popen(
        [sys.executable, "-m", "armtrack.server.cli", "serve", "--port", str(port),
         "--data-dir", str(data_dir)], stdout=log, stderr=subprocess.STDOUT, env=env,
        preexec_fn=(lambda: pin(cpu)) if cpu is not None else None)
    log.close()
    deadline = time.monotonic() + 180  # on a loaded machine its start took over 60 s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError("server exited: "
                               + (data_dir / "server.log").read_text()[-2000:])
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                return process
        except httpx.HTTPError:
            time.sleep(0.1)
    process.kill()
    raise RuntimeError("server did not start: " + (data_dir / "server.log").read_text()[-2000:])


def stop_server(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: Where a profile sample belongs: the first rule (in this order) naming a function on its
#: stack, by (stage, function-name prefix).
STAGES = [
    ("live estimation (LiveWorker._process, compute pool)", "LiveWorker._process "),
    ("group commit (GroupWriter._commit, writer thread)", "GroupWriter._commit "),
    ("  ingest: check_samples (validation, np.array)", "check_samples "),
    ("  ingest: JSON parse (protocol.parse)", "parse (server/ingest/protocol.py"),
    ("ingest: IngestConnection._handle, rest", "IngestConnection._handle "),
    ("acks (IngestConnection._ack_loop/send)", "IngestConnection._ack_loop "),
    ("live feed: /ws/live send (endpoint.live)", "live (server/live/endpoint.py"),
    ("live worker loop (LiveWorker._run, publish)", "LiveWorker._run "),
    ("WebSocket framing/deflate (websockets, uvicorn)", "(websockets/"),
    ("WebSocket framing/deflate (websockets, uvicorn)", "(uvicorn/protocols/"),
    ("other armtrack server code", "(server/"),
    ("ASGI/starlette/fastapi plumbing", "(starlette/"),
    ("ASGI/starlette/fastapi plumbing", "(fastapi/"),
    ("asyncio event loop itself", "(asyncio/"),
]


def summarize_profile(raw: Path, top: int) -> list[tuple[str, float, float]]:
    """From py-spy's collapsed stacks: the stages of :data:`STAGES` (% of samples), then the
    busiest functions by own time (own %, inclusive %)."""
    own: Counter[str] = Counter()
    inclusive: Counter[str] = Counter()
    stages: Counter[str] = Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack:
            continue
        count = int(count_text)
        total += count
        frames = [re.sub(r":\d+\)$", ")", f) for f in stack.split(";")]
        # a thread's name frame ("thread (0x...)") and "process ..." are not functions
        frames = [f for f in frames if not f.startswith(("process ", "thread "))]
        if frames:
            own[frames[-1]] += count
        for f in set(frames):
            inclusive[f] += count
        stage = "other (threading, idle pool workers, ...)"
        inner = [f for f in frames if "(server/cli.py" not in f and "(server/commands/" not in f]
        for name, key in STAGES:
            if any(key in f for f in inner):
                stage = name
                break
        stages[stage] += count
    if not total:
        return []
    rows = [("(by stage: % of samples)", 0.0, 0.0)]
    rows += [(name, 100.0 * c / total, 100.0 * c / total)
             for name, c in sorted(stages.items(), key=lambda kv: -kv[1])]
    rows.append(("(busiest functions: own %, inclusive %)", 0.0, 0.0))
    rows += [(f, 100.0 * c / total, 100.0 * inclusive[f] / total)
             for f, c in own.most_common(top)]
    rows.append((f"(samples: {total})", 0.0, 0.0))
    return rows


def run_one(n: int, args: argparse.Namespace, recording_path: Path, tmp: Path) -> Run:
    import httpx
    import numpy as np

    run = Run(n)
    data_dir = tmp / f"server-{n}-{time.monotonic_ns()}"
    data_dir.mkdir()
    env = {f"ARMTRACK_{k.upper()}": str(v) for k, v in args.server_env}
    broker = None
    if args.database_url:
        env["ARMTRACK_DATABASE_URL"] = fresh_database(args.database_url)
    else:  # one SQLite file for create-user and the server (their data dirs differ)
        env["ARMTRACK_DATABASE_URL"] = f"sqlite:///{(data_dir / 'armtrack.db').resolve()}"
    if args.instances > 1:
        broker, env["ARMTRACK_BROKER_URL"] = start_broker(data_dir)
    done = subprocess.run([sys.executable, "-m", "armtrack.server.cli", "create-user",
                           THERAPIST, "--password", PASSWORD, "--data-dir", str(data_dir)],
                          capture_output=True, text=True, env={**os.environ, **env})
    if done.returncode != 0:
        raise RuntimeError(f"create-user failed: {done.stderr}")
    ports, servers = [], []
    for k in range(args.instances):
        instance_dir = data_dir / f"instance-{k}"
        instance_dir.mkdir()
        ports.append(free_port())
        servers.append(start_server(instance_dir, ports[-1], args.server_cpu, env))
    server = servers[0]
    port = ports[0]
    sampler = Samplers([Sampler(s.pid) for s in servers])
    base = f"http://127.0.0.1:{port}"
    profiler = None
    try:
        http = httpx.Client(base_url=base, timeout=60)
        answer = http.post("/api/auth/token", data={"username": THERAPIST,
                                                    "password": PASSWORD})
        answer.raise_for_status()
        token = answer.json()["access_token"]
        http.headers["Authorization"] = f"Bearer {token}"

        def patient_device(i: int) -> dict:
            p = http.post("/api/patients", json={"name": f"patient {i}", "side": "right",
                                                 "height_m": 1.75})
            p.raise_for_status()
            pid = p.json()["id"]
            d = http.post(f"/api/patients/{pid}/devices", json={"name": f"kit {i}"})
            d.raise_for_status()
            return {"patient_id": pid, "token": d.json()["token"]}

        made = time.monotonic()
        warmup = patient_device(-1)
        patients = [patient_device(i) for i in range(n)]
        setup_s = time.monotonic() - made
        config = {
            "recording": str(recording_path), "rows_per_message": args.rows_per_message,
            "ingest_url": f"ws://127.0.0.1:{port}/ws/ingest",
            "live_url": f"ws://127.0.0.1:{port}/ws/live", "therapist_token": token,
            "patients": patients, "warmup": warmup, "speed": 1.0,
            "stagger_s": args.stagger, "deflate": not args.no_deflate,
            "ingest_urls": [f"ws://127.0.0.1:{p}/ws/ingest" for p in ports],
            "live_urls": [f"ws://127.0.0.1:{p}/ws/live" for p in ports],
        }
        config_path = data_dir / "client.json"
        output_path = data_dir / "client-result.json"
        config_path.write_text(json.dumps(config))
        run.load_before = load_average()
        print(f"  N={n}: {n} patients and devices made in {setup_s:.1f} s; load "
              f"{run.load_before}; streaming...", flush=True)
        sampler.start()
        client = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--client", str(config_path),
             str(output_path)], preexec_fn=(lambda: pin(args.client_cpu))
            if args.client_cpu is not None else None)
        client_sampler = Sampler(client.pid)
        client_sampler.start()
        if args.profile:
            profiler = threading.Thread(target=profile_server, daemon=True,
                                        args=(server.pid, output_path, data_dir, args, run))
            profiler.start()
        limit = args.stagger + args.duration * 3 + 300
        try:
            client.wait(limit)
        except subprocess.TimeoutExpired:
            client.kill()
            client.wait()
            run.notes.append(f"client killed after {limit:.0f} s")
        client_sampler.stop()
        if profiler is not None:
            profiler.join(timeout=args.duration + 60)
        run.load_after = load_average()
        if client.returncode != 0 or not output_path.exists():
            run.why = f"client failed (exit {client.returncode})"
            sampler.stop()
            return run
        result = json.loads(output_path.read_text())

        # the server's own count of stored rows, per session
        stored = 0
        for session_id in result["sessions"]:
            if session_id is None:
                continue
            answer = http.get(f"/api/sessions/{session_id}")
            answer.raise_for_status()
            stored += answer.json()["samples"]
        sampler.stop()
    finally:
        for s in servers:
            stop_server(s)
        if broker is not None:
            stop_server(broker)
        if sampler.is_alive():
            sampler.stop()

    def floats(key: str) -> np.ndarray:
        return np.frombuffer(bytes.fromhex(result[key]), dtype=np.float64)

    ack, lat, ages = (floats(k) for k in ("ack_latencies", "pose_latencies",
                                          "pose_ages"))
    run.rows_planned, run.rows_sent = result["rows_planned"], result["rows_sent"]
    run.rows_acked, run.rows_stored = result["rows_acked"], stored
    run.loss = run.rows_sent - stored
    run.duration_s = result["last_bye"] - result["first_ready"]
    run.samples_per_s = stored / run.duration_s if run.duration_s > 0 else math.nan
    run.messages_per_s = result["messages_total"] / run.duration_s if run.duration_s else 0
    if len(ack):
        run.ack_p50_ms, run.ack_p99_ms = (1e3 * float(np.percentile(ack, q)) for q in (50, 99))
    if len(lat):
        run.pose_p50_ms, run.pose_p99_ms = (1e3 * float(np.percentile(lat, q))
                                            for q in (50, 99))
        run.pose_max_ms = 1e3 * float(lat.max())
    if len(ages):
        run.age_p50_ms, run.age_p99_ms = (1e3 * float(np.percentile(ages, q))
                                          for q in (50, 99))
    run.poses = result["poses"]
    rates = [r for r in result["pose_rate"] if r > 0]
    run.poses_per_s_viewer = float(np.median(rates)) if rates else 0.0
    steady0, steady1 = result["last_start"] + 1.0, result["first_bye"]
    if len(lat):
        run.notes.append(slow_poses_by_phase(lat, floats("pose_latency_at"), args.limit_ms,
                                             result["first_ready"], steady0, steady1))
    run.steady_s = max(steady1 - steady0, 0.0)
    if run.steady_s < 5.0:
        run.notes.append(f"steady window only {run.steady_s:.1f} s: CPU over the whole run")
        steady0, steady1 = result["first_ready"], result["last_bye"]
    run.server_cpu_pct, rss = sampler.window(steady0, steady1)
    live_cpu = sampler.live_window(steady0, steady1)
    run.notes.append(f"server CPU {run.server_cpu_pct:.0f} % = main process "
                     f"{run.server_cpu_pct - live_cpu:.0f} % + live estimation process "
                     f"{live_cpu:.0f} %")
    run.server_cpu_run_pct, _ = sampler.window(result["first_ready"], result["last_bye"])
    run.server_rss_mb = rss / 2**20
    run.server_hwm_mb = sampler.hwm / 2**20
    run.client_cpu_pct, _ = client_sampler.window(steady0, steady1)
    run.errors, run.refused = result["errors"], result["refused"]
    run.reconnects = result["reconnects"]
    run.kits_failed, run.viewers_failed = result["kits_failed"], result["viewers_failed"]
    for key in ("error_examples", "kit_error_examples", "viewer_error_examples"):
        if result[key]:
            run.notes.append(f"{key}: {result[key][:2]}")
    run.notes.append("WebSocket extensions the server took for the viewers: "
                     + (", ".join(result["viewer_extensions"]) or "none"))
    if result["warmup_error"]:
        run.notes.append(f"warm-up kit: {result['warmup_error']}")
    if run.client_cpu_pct > 90:
        run.notes.append(f"client CPU {run.client_cpu_pct:.0f} %: the client may be the limit")

    problems = []
    if run.loss or run.rows_sent != run.rows_planned or run.rows_acked != run.rows_sent:
        problems.append(f"loss: planned {run.rows_planned}, sent {run.rows_sent}, acked "
                        f"{run.rows_acked}, stored {stored}")
    if run.errors or run.refused or run.kits_failed or run.viewers_failed:
        problems.append(f"errors {run.errors}, refused {run.refused}, kits failed "
                        f"{run.kits_failed}, viewers failed {run.viewers_failed}")
    if run.reconnects:
        problems.append(f"{run.reconnects} reconnects")
    if not len(lat):
        problems.append("no poses")
    elif run.pose_p99_ms > args.limit_ms:
        problems.append(f"pose p99 {run.pose_p99_ms:.0f} ms > {args.limit_ms:g} ms")
    run.holds = not problems
    run.why = "; ".join(problems) if problems else "holds"
    return run


def slow_poses_by_phase(latencies: np.ndarray, arrived: np.ndarray, limit_ms: float,
                        first_ready: float, steady0: float, steady1: float) -> str:
    """Where the poses over ``limit_ms`` fell: while kits were still starting (first
    ``ready`` → last start + 1 s), steady (every kit streaming), or ending (first ``bye``
    on); with the worst second of the run. Times are the viewers' arrival times."""
    import numpy as np

    slow = latencies > limit_ms / 1e3
    phases = {"starting": arrived < steady0, "steady": (arrived >= steady0) & (arrived < steady1),
              "ending": arrived >= steady1}
    parts = [f"{name} {int(np.count_nonzero(slow & inside))} of {int(np.count_nonzero(inside))}"
             for name, inside in phases.items()]
    worst = ""
    if slow.any():
        seconds = np.floor(arrived[slow] - first_ready).astype(int)
        second, count = np.unique(seconds, return_counts=True)
        k = int(np.argmax(count))
        worst = (f"; worst second {int(second[k])}-{int(second[k]) + 1} s after the first "
                 f"ready ({int(count[k])} slow; steady {steady0 - first_ready:.1f}–"
                 f"{steady1 - first_ready:.1f} s)")
    return f"poses over {limit_ms:g} ms: " + ", ".join(parts) + worst


def profile_server(pid: int, output_path: Path, data_dir: Path, args: argparse.Namespace,
                   run: Run) -> None:
    """py-spy on the server through the steady window: waits for the last kit's start
    (stagger + warm-up), then records ``--profile-s`` seconds."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        run.notes.append("py-spy not found: pip install py-spy")
        return
    time.sleep(args.profile_delay)
    raw = data_dir / "profile.txt"
    seconds = max(int(min(args.profile_s, args.duration - 5)), 3)
    done = subprocess.run([spy, "record", "--pid", str(pid), "--duration", str(seconds),
                           "--rate", "100", "--format", "raw", "--output", str(raw),
                           *(["--gil"] if args.profile_gil else [])],
                          capture_output=True, text=True,
                          preexec_fn=(lambda: pin(args.client_cpu))
                          if args.client_cpu is not None else None)
    if done.returncode != 0 or not raw.exists():
        run.notes.append(f"py-spy failed: {done.stderr.strip()[-300:]}")
        return
    run.profile = summarize_profile(raw, args.profile_top)
    if args.keep_profiles:
        target = RESULTS.parent / f"ingest-profile-{run.n}.txt"
        shutil.copy(raw, target)


def simulate_recording(duration_s: float, path: Path) -> tuple[int, float]:
    from armtrack.estimator.recording import write_recording
    from armtrack.estimator.simulation import SimulationConfig, simulate

    # elbow flexion, repetitions until the session reaches the duration (calibration first)
    reps = 1
    while True:
        result = simulate(SimulationConfig(exercise="elbow_flexion", repetitions=reps, seed=7))
        length = result.truth.t[-1] - result.truth.t[0]
        if length >= duration_s or reps > 500:
            break
        reps = max(reps + 1, int(reps * duration_s / max(length, 1e-9)))
    write_recording(result.recording, path)
    rows = sum(len(s.t) for s in result.recording.sensors.values())
    return rows, float(length)


def fmt(x: float, digits: int = 0) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


HEADER = (f"{'N':>5} {'holds':>5} {'samples/s':>10} {'loss':>5} {'ack p50':>7} {'p99':>6} "
          f"{'pose p50':>8} {'p99':>6} {'age p50':>7} {'p99':>6} {'poses/s':>7} "
          f"{'srv CPU%':>8} {'RSS MB':>6} {'cli CPU%':>8} {'err':>4}  load before/after")


def row_text(r: Run) -> str:
    return (f"{r.n:5d} {'yes' if r.holds else 'NO':>5} {fmt(r.samples_per_s):>10} "
            f"{r.loss:5d} {fmt(r.ack_p50_ms):>7} {fmt(r.ack_p99_ms):>6} "
            f"{fmt(r.pose_p50_ms, 1):>8} {fmt(r.pose_p99_ms, 1):>6} {fmt(r.age_p50_ms):>7} "
            f"{fmt(r.age_p99_ms):>6} {fmt(r.poses_per_s_viewer, 1):>7} "
            f"{fmt(r.server_cpu_pct):>8} {fmt(r.server_rss_mb):>6} "
            f"{fmt(r.client_cpu_pct):>8} {r.errors + r.refused + r.kits_failed + r.reconnects:4d}"
            f"  {r.load_before} / {r.load_after}")


CSV_COLUMNS = ["date", "commit", "mode", "n", "holds", "why", "duration_s", "rows_planned",
               "rows_sent", "rows_acked", "rows_stored", "loss", "samples_per_s",
               "messages_per_s", "ack_p50_ms", "ack_p99_ms", "pose_p50_ms", "pose_p99_ms",
               "pose_max_ms", "age_p50_ms", "age_p99_ms", "poses", "poses_per_s_viewer",
               "server_cpu_pct", "server_cpu_run_pct", "server_rss_mb", "server_hwm_mb",
               "client_cpu_pct", "errors", "refused", "reconnects", "kits_failed",
               "viewers_failed", "steady_s", "load_before", "load_after", "settings", "notes"]


def write_csv_row(r: Run, mode: str, version: str, settings: str, fresh: bool) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    new = fresh or not RESULTS.exists()
    with open(RESULTS, "w" if new else "a", encoding="utf-8", newline="") as file:
        writer = csv.writer(file, lineterminator="\n")
        if new:
            writer.writerow(CSV_COLUMNS)
        values = asdict(r)
        row = []
        for column in CSV_COLUMNS:
            if column == "date":
                row.append(datetime.now().isoformat(timespec="seconds"))
            elif column == "commit":
                row.append(version)
            elif column == "mode":
                row.append(mode)
            elif column == "settings":
                row.append(settings)
            elif column == "notes":
                row.append(" | ".join(r.notes))
            elif column == "holds":
                row.append("yes" if r.holds else "no")
            else:
                value = values[column]
                row.append(f"{value:.4g}" if isinstance(value, float) else value)
        writer.writerow(row)


def main(argv: list[str] | None = None) -> int:
    if argv is None and len(sys.argv) == 4 and sys.argv[1] == "--client":
        return client_entry(sys.argv[2], sys.argv[3])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--patients", type=int, nargs="+", default=[50, 200],
                        help="the N to run, each on a fresh server (default 50 200)")
    parser.add_argument("--find-max", action="store_true",
                        help="double N from --start until a run fails, then bisect")
    parser.add_argument("--start", type=int, default=50, help="first N of --find-max")
    parser.add_argument("--resolution", type=float, default=0.1,
                        help="--find-max stops when the gap is below this share of N")
    parser.add_argument("--max-n", type=int, default=4000, help="largest N --find-max tries")
    parser.add_argument("--limit-ms", type=float, default=100.0,
                        help="pose latency p99 a run must stay under [ms] (default 100)")
    parser.add_argument("--duration", type=float, default=40.0,
                        help="the simulated exercise [s], calibration included (default 40)")
    parser.add_argument("--stagger", type=float, default=5.0,
                        help="the kits' starts are spread over this many seconds (default 5)")
    parser.add_argument("--rows-per-message", type=int, default=10)
    parser.add_argument("--no-deflate", action="store_true",
                        help="kits and viewers do not offer permessage-deflate (the "
                             "emulator and browsers do by default; a microcontroller may not)")
    parser.add_argument("--server-cpu", type=int, default=None,
                        help="the CPU for the server (default: the last allowed)")
    parser.add_argument("--client-cpu", type=int, default=None,
                        help="the CPU for the client and py-spy (default: the first allowed)")
    parser.add_argument("--pin", action="store_true",
                        help="pin the server (with its live estimation process) to one CPU "
                             "and the client to another")
    parser.add_argument("--no-pin", action="store_true",
                        help="pin nothing (the default; kept for old command lines)")
    parser.add_argument("--server-env", nargs=2, action="append", default=[],
                        metavar=("NAME", "VALUE"),
                        help="a server setting, e.g. --server-env live_poses_hz 10 "
                             "(ARMTRACK_LIVE_POSES_HZ)")
    parser.add_argument("--profile", action="store_true",
                        help="py-spy the server through each run's steady window")
    parser.add_argument("--profile-s", type=float, default=20.0)
    parser.add_argument("--profile-all", dest="profile_gil", action="store_false",
                        help="sample every running thread, not only the one holding the GIL "
                             "(on one pinned CPU, threads waiting for it count too)")
    parser.add_argument("--profile-top", type=int, default=15)
    parser.add_argument("--keep-profiles", action="store_true",
                        help="copy py-spy's collapsed stacks to bench/results/")
    parser.add_argument("--instances", type=int, default=1,
                        help="server instances on one PostgreSQL and one broker")
    parser.add_argument("--database-url", default=None,
                        help="PostgreSQL server URL (a fresh database per run); default for "
                        "--instances > 1: ARMTRACK_TEST_POSTGRES_URL")
    parser.add_argument("--fresh-csv", action="store_true",
                        help="rewrite bench/results/ingest.csv instead of appending")
    args = parser.parse_args(argv)
    if args.instances > 1 and not args.database_url:
        args.database_url = os.environ.get("ARMTRACK_TEST_POSTGRES_URL")
        if not args.database_url:
            parser.error("--instances > 1 needs PostgreSQL: --database-url or "
                         "ARMTRACK_TEST_POSTGRES_URL (eval \"$(.ci/postgres start)\")")

    raise_fd_limit()
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not (args.pin or args.server_cpu is not None or args.client_cpu is not None) \
            or args.no_pin or len(allowed) < 2:
        args.server_cpu = args.client_cpu = None
        pinned = "not pinned"
    else:
        args.server_cpu = allowed[-1] if args.server_cpu is None else args.server_cpu
        args.client_cpu = allowed[0] if args.client_cpu is None else args.client_cpu
        pin(args.client_cpu)  # this process too (it only samples /proc)
        pinned = f"server on CPU {args.server_cpu}, client on CPU {args.client_cpu}"
    # the stagger, the warm-up (~a few s) and 2 s: then the profile
    args.profile_delay = args.stagger + 8.0

    version = code_version()
    print(f"machine: {os.cpu_count()} cores, {pinned}; load average {load_average()} "
          f"(1/5/15 min; other work on the machine shows in the numbers)")
    print(f"server: commit {version}")
    settings = " ".join(f"ARMTRACK_{k.upper()}={v}" for k, v in args.server_env) or "defaults"
    if args.instances > 1 or args.database_url:
        settings += (f"; {args.instances} instance(s) on PostgreSQL"
                     + (" + Redis broker" if args.instances > 1 else ""))
    settings += ("; clients without deflate" if args.no_deflate
                 else "; clients offer permessage-deflate")
    print(f"server settings: {settings}")

    with tempfile.TemporaryDirectory(prefix="armtrack-bench-ingest-") as tmp_name:
        tmp = Path(tmp_name)
        recording_path = tmp / "exercise.csv"
        rows, length = simulate_recording(args.duration, recording_path)
        print(f"recording: simulated elbow_flexion, 3 sensors x 100 Hz, 9-axis, {length:.1f} s "
              f"(calibration included), {rows:,} rows; {args.rows_per_message} rows a "
              f"message; real time; starts spread over {args.stagger:g} s")
        print(f"a run holds with zero loss, no errors and pose latency p99 < "
              f"{args.limit_ms:g} ms\n")

        runs: list[Run] = []
        mode = "find-max" if args.find_max else "list"

        def measure(n: int) -> Run:
            r = run_one(n, args, recording_path, tmp)
            runs.append(r)
            print(HEADER)
            print(row_text(r))
            print(f"      {r.why}; {fmt(r.messages_per_s)} messages/s in, {r.poses:,} poses "
                  f"out; server CPU over the whole run {fmt(r.server_cpu_run_pct)} %, "
                  f"RSS peak {fmt(r.server_hwm_mb)} MB; steady window {r.steady_s:.0f} s")
            for note in r.notes:
                print(f"      note: {note}")
            if r.profile:
                print(f"      server profile (py-spy, {args.profile_s:g} s of the steady "
                      f"window; % of samples, own / inclusive):")
                for name, own, inclusive in r.profile:
                    if name.startswith("("):
                        print(f"        {name}")
                    else:
                        print(f"        {own:5.1f} {inclusive:5.1f}  {name[:110]}")
            print(flush=True)
            write_csv_row(r, mode, version, settings, args.fresh_csv and len(runs) == 1)
            return r

        if args.find_max:
            good, bad = 0, None
            n = args.start
            while n <= args.max_n:
                if measure(n).holds:
                    good = n
                    n *= 2
                else:
                    bad = n
                    break
            while bad is not None and bad - good > max(args.resolution * good, 1):
                n = (good + bad) // 2
                if measure(n).holds:
                    good = n
                else:
                    bad = n
        else:
            for n in args.patients:
                measure(n)

        print("summary")
        print(HEADER)
        for r in sorted(runs, key=lambda r: r.n):
            print(row_text(r))
        held = [r.n for r in runs if r.holds]
        print(f"\nlargest N that held: {max(held) if held else 'none'}"
              + (f" (first that did not: {min(r.n for r in runs if not r.holds)})"
                 if any(not r.holds for r in runs) else ""))
    print(f"written: {RESULTS.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
