"""Soak: N emulated patients stream for a long time against one server; memory and latency
are sampled every ``--interval`` seconds. Run by hand (``python bench/soak.py --patients 25
--duration 1800``); CI runs a 60-second version (``tests/test_reliability_soak.py``).

A fresh ``armtrack serve`` subprocess (temporary data folder, SQLite, default settings;
pinned to one CPU on a 2-core machine, this client to the other, as in ``ingest.py``), a
therapist and N patients with a device each. Every patient has one ``/ws/live`` viewer,
connected for the whole soak, and a kit (``KitEmulator``: 3 sensors × 100 Hz, 9-axis, 10
rows a message, real time) that plays one simulated ``elbow_flexion`` session of
``--session-s`` seconds after another (each a new session: ``bye``, batch processing of
the closed session, a new ``hello``), so that sessions open and close all along, as in a
clinic. The kits' first starts are spread over ``--stagger`` seconds; no session starts
that could not end before ``--duration``.

Every ``--interval`` s a row: the server's RSS (``VmRSS``) and CPU % over the interval, the
pose latency p50/p99/max over the interval (the server's ``latency_s`` of each ``pose``
the viewers received: newest sample's arrival → publication), the ack latency p99, the
sample rows acked per second, live kits, errors so far. Written to
``bench/results/soak.csv`` (``--output``) as it goes and plotted to ``soak.png`` at the end.

Verdict, printed and returned: **zero loss** (every session's stored ``samples``, from
REST, equal the rows its kit sent; every message acked, nothing refused, no kit failed);
**pose p99 < --limit-ms** (100) over the whole soak; **memory bounded**: the slope of a
least-squares line through RSS over the second half of the soak (after warm-up), in MB
per minute, under ``--max-slope`` (default 0.5 MB/min: 30 MB an hour).
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import math
import os
import subprocess
import sys
import tempfile
import time
from array import array
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import ingest as bench_ingest  # bench/ingest.py: the server, /proc, the recording

REPO = bench_ingest.REPO
RESULTS_DIR = REPO / "bench" / "results"
COLUMNS = ["elapsed_s", "rss_mb", "server_cpu_pct", "pose_p50_ms", "pose_p99_ms",
           "pose_max_ms", "poses", "ack_p99_ms", "rows_per_s", "live_kits", "sessions",
           "errors"]


@dataclass
class SoakResult:
    n: int
    duration_s: float
    rows: list[dict] = field(default_factory=list)  # one per interval
    sessions: int = 0
    rows_sent: int = 0
    rows_stored: int = 0
    loss: int = 0
    messages: int = 0
    acked: int = 0
    refused: int = 0
    errors: int = 0
    reconnects: int = 0
    kits_failed: int = 0
    viewer_drops: int = 0
    problems_seen: list[str] = field(default_factory=list)
    poses: int = 0
    pose_p50_ms: float = math.nan
    pose_p99_ms: float = math.nan
    pose_max_ms: float = math.nan
    ack_p99_ms: float = math.nan
    rss_first_mb: float = math.nan
    rss_last_mb: float = math.nan
    rss_max_mb: float = math.nan
    rss_slope_mb_per_min: float = math.nan
    server_cpu_pct: float = math.nan
    holds: bool = False
    why: str = ""


def rss_slope(rows: list[dict], skip_fraction: float = 0.5) -> float:
    """Least-squares slope [MB/min] of RSS over the rows after ``skip_fraction`` of the
    time (the warm-up: imports, numba, the first sessions' buffers)."""
    import numpy as np

    if len(rows) < 3:
        return math.nan
    t = np.array([r["elapsed_s"] for r in rows])
    rss = np.array([r["rss_mb"] for r in rows])
    keep = t >= t[0] + skip_fraction * (t[-1] - t[0])
    if keep.sum() < 3:
        keep[:] = True
    slope = np.polyfit(t[keep] / 60.0, rss[keep], 1)[0]
    return float(slope)


async def _viewer(url: str, token: str, latencies: array, stamps: array,
                  stop: asyncio.Event, result: SoakResult) -> None:
    """One therapist's ``/ws/live`` feed for the whole soak (reconnects if dropped)."""
    from websockets.asyncio.client import connect

    while not stop.is_set():
        try:
            async with connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                               open_timeout=60, max_size=2**22, compression=None) as ws:
                while not stop.is_set():
                    try:
                        async with asyncio.timeout(1.0):
                            text = await ws.recv()
                    except TimeoutError:
                        continue
                    if not text.startswith('{"kind":"pose"'):
                        continue
                    i = text.rfind('"latency_s":')
                    if i >= 0:
                        end = i + 12
                        while text[end] not in ",}":
                            end += 1
                        latencies.append(float(text[i + 12:end]))
                        stamps.append(time.monotonic())
        except Exception as exc:  # counted; a soak's viewer should never drop
            if not stop.is_set():
                result.viewer_drops += 1
                result.problems_seen.append(f"viewer: {type(exc).__name__}: {exc}")
                await asyncio.sleep(1.0)


async def soak_async(*, base: str, token: str, patients: list[dict], recording_path: Path,
                     duration_s: float, interval_s: float, stagger_s: float,
                     server_pid: int, output: Path | None, quiet: bool = False
                     ) -> SoakResult:
    import httpx
    import numpy as np
    from armtrack.estimator.recording import read_recording
    from armtrack.server.emulator import KitEmulator

    recording = read_recording(recording_path)
    plan = bench_ingest.make_cached_plan(recording, 10)
    session_s = float(plan.times[-1] - plan.times[0])
    n = len(patients)
    result = SoakResult(n, duration_s)
    ws_base = base.replace("http://", "ws://")
    stop = asyncio.Event()
    latencies, stamps = array("d"), array("d")
    kits: list[KitEmulator] = []
    live = [0]
    sent_by_session: dict[int, int] = {}
    begin = time.monotonic()
    deadline = begin + duration_s

    viewers = [asyncio.create_task(_viewer(f"{ws_base}/ws/live?patient={p['patient_id']}",
                                           token, latencies, stamps, stop, result))
               for p in patients]
    await asyncio.sleep(0.5)

    async def patient_loop(i: int, p: dict) -> None:
        await asyncio.sleep(stagger_s * i / max(n, 1))
        while time.monotonic() + session_s + 2.0 < deadline:
            kit = KitEmulator(recording, f"{ws_base}/ws/ingest", p["token"],
                              device=f"soak-kit-{i}", speed=1.0, ack_timeout_s=30.0,
                              open_timeout_s=60.0)
            kit.plan = plan
            kits.append(kit)
            live[0] += 1
            try:
                await kit.run()
            except Exception as exc:
                result.kits_failed += 1
                result.problems_seen.append(f"kit {i}: {type(exc).__name__}: {exc}")
                await asyncio.sleep(1.0)
            finally:
                live[0] -= 1
                if kit.stats.session is not None:
                    sent_by_session[kit.stats.session] = kit.stats.rows_sent

    loops = [asyncio.create_task(patient_loop(i, p)) for i, p in enumerate(patients)]

    writer = None
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        handle = open(output, "w", encoding="utf-8", newline="")
        writer = csv.DictWriter(handle, COLUMNS, lineterminator="\n")
        writer.writeheader()
    last_cpu = bench_ingest.proc_cpu_s(server_pid)
    last_t = time.monotonic()
    pose_index = 0
    ack_index: dict[int, int] = {}
    rows_acked_before = 0
    try:
        while True:
            all_done = all(loop.done() for loop in loops)
            wait = min(interval_s, max(deadline - time.monotonic(), 0.0))
            if not all_done:
                await asyncio.wait(loops, timeout=max(wait, 0.05))
            now = time.monotonic()
            if all_done and now - last_t < 1.0:
                break  # the kits ended right after the last row: nothing more to say
            cpu = bench_ingest.proc_cpu_s(server_pid)
            rss, _ = bench_ingest.proc_rss(server_pid)
            lat = np.array(latencies[pose_index:], dtype=np.float64)  # a copy: the
            # viewers go on appending to the array
            pose_index += len(lat)
            acks = []
            for k, kit in enumerate(kits):
                start = ack_index.get(k, 0)
                acks.extend(kit.stats.latencies_s[start:])
                ack_index[k] = len(kit.stats.latencies_s)
            rows_acked = sum(k.stats.rows_acked for k in kits)
            span = max(now - last_t, 1e-9)
            row = {
                "elapsed_s": round(now - begin, 2),
                "rss_mb": round((rss or 0) / 2**20, 2),
                "server_cpu_pct": round(100.0 * (cpu - last_cpu) / span, 1)
                if cpu is not None and last_cpu is not None else math.nan,
                "pose_p50_ms": round(1e3 * float(np.percentile(lat, 50)), 2) if len(lat)
                else math.nan,
                "pose_p99_ms": round(1e3 * float(np.percentile(lat, 99)), 2) if len(lat)
                else math.nan,
                "pose_max_ms": round(1e3 * float(lat.max()), 2) if len(lat) else math.nan,
                "poses": len(lat),
                "ack_p99_ms": round(1e3 * float(np.percentile(acks, 99)), 1) if acks
                else math.nan,
                "rows_per_s": round((rows_acked - rows_acked_before) / span, 1),
                "live_kits": live[0],
                "sessions": len(kits),
                "errors": sum(len(k.stats.errors) for k in kits) + result.kits_failed,
            }
            result.rows.append(row)
            if writer is not None:
                writer.writerow(row)
                handle.flush()
            if not quiet:
                print("  ".join(f"{c}={row[c]}" for c in COLUMNS), flush=True)
            last_cpu, last_t, rows_acked_before = cpu, now, rows_acked
            if all_done:
                break
    finally:
        for loop in loops:
            if not loop.done():
                loop.cancel()
        await asyncio.gather(*loops, return_exceptions=True)
        await asyncio.sleep(1.5)  # the last poses on their way
        stop.set()
        await asyncio.gather(*viewers, return_exceptions=True)
        if writer is not None:
            handle.close()

    # what is stored, from REST
    async with httpx.AsyncClient(base_url=base, timeout=60,
                                 headers={"Authorization": f"Bearer {token}"}) as http:
        for session_id, sent in sent_by_session.items():
            answer = await http.get(f"/api/sessions/{session_id}")
            stored = answer.json()["samples"] if answer.status_code == 200 else 0
            result.rows_stored += stored
            result.rows_sent += sent
            if stored != sent:
                result.problems_seen.append(f"session {session_id}: sent {sent}, "
                                            f"stored {stored}")
    result.sessions = len(sent_by_session)
    result.loss = result.rows_sent - result.rows_stored
    result.messages = sum(k.stats.total for k in kits)
    result.acked = sum(k.stats.acked for k in kits)
    result.refused = sum(k.stats.refused for k in kits)
    result.errors = sum(len(k.stats.errors) for k in kits)
    result.reconnects = sum(k.stats.reconnects for k in kits)
    lat = np.array(latencies, dtype=np.float64)
    result.poses = len(lat)
    if len(lat):
        result.pose_p50_ms, result.pose_p99_ms = (1e3 * float(np.percentile(lat, q))
                                                  for q in (50, 99))
        result.pose_max_ms = 1e3 * float(lat.max())
    acks = [x for k in kits for x in k.stats.latencies_s]
    if acks:
        result.ack_p99_ms = 1e3 * float(np.percentile(acks, 99))
    rss = [r["rss_mb"] for r in result.rows if r["rss_mb"] > 0]
    if rss:
        result.rss_first_mb, result.rss_last_mb, result.rss_max_mb = rss[0], rss[-1], max(rss)
    result.rss_slope_mb_per_min = rss_slope(result.rows)
    cpus = [r["server_cpu_pct"] for r in result.rows if not math.isnan(r["server_cpu_pct"])]
    result.server_cpu_pct = float(np.median(cpus)) if cpus else math.nan
    return result


def judge(result: SoakResult, limit_ms: float, max_slope: float) -> SoakResult:
    problems = []
    if (result.loss or result.acked != result.messages or result.refused or result.errors
            or result.kits_failed or result.sessions == 0):
        problems.append(f"loss {result.loss} rows; acked {result.acked}/{result.messages}, "
                        f"refused {result.refused}, errors {result.errors}, kits failed "
                        f"{result.kits_failed}")
    if not result.poses:
        problems.append("no poses")
    elif not result.pose_p99_ms < limit_ms:
        problems.append(f"pose p99 {result.pose_p99_ms:.0f} ms ≥ {limit_ms:g} ms")
    if not result.rss_slope_mb_per_min < max_slope:
        problems.append(f"RSS grows {result.rss_slope_mb_per_min:.2f} MB/min "
                        f"(limit {max_slope:g})")
    result.holds = not problems
    result.why = "; ".join(problems) if problems else "holds"
    return result


def plot(result: SoakResult, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = result.rows
    minutes = np.array([r["elapsed_s"] for r in rows]) / 60.0
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    rss = np.array([r["rss_mb"] for r in rows])
    axes[0].plot(minutes, rss, ".-", label="server RSS")
    if len(rows) >= 3 and not math.isnan(result.rss_slope_mb_per_min):
        keep = minutes >= minutes[0] + 0.5 * (minutes[-1] - minutes[0])
        fit = np.polyfit(minutes[keep], rss[keep], 1)
        axes[0].plot(minutes[keep], np.polyval(fit, minutes[keep]), "--",
                     label=f"fit, 2nd half: {fit[0]:+.2f} MB/min")
    axes[0].set_ylabel("RSS [MB]")
    axes[0].legend(loc="lower right")
    for key, label in (("pose_p50_ms", "pose p50"), ("pose_p99_ms", "pose p99"),
                       ("ack_p99_ms", "ack p99")):
        axes[1].plot(minutes, [r[key] for r in rows], ".-", label=label)
    axes[1].axhline(100, color="red", linewidth=1, label="100 ms")
    axes[1].set_ylabel("latency per interval [ms]")
    axes[1].set_yscale("log")
    axes[1].legend(loc="upper right", fontsize=8)
    axes[2].plot(minutes, [r["rows_per_s"] for r in rows], ".-", label="samples/s acked")
    axes[2].set_ylabel("samples/s")
    twin = axes[2].twinx()
    twin.plot(minutes, [r["server_cpu_pct"] for r in rows], ".-", color="gray",
              label="server CPU %")
    twin.set_ylabel("server CPU [%]")
    axes[2].set_xlabel("minutes")
    axes[2].legend(loc="lower left", fontsize=8)
    twin.legend(loc="lower right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run_soak(n: int, duration_s: float, *, interval_s: float = 10.0, session_s: float = 60.0,
             stagger_s: float = 5.0, server_cpu: int | None = None,
             output: Path | None = None, server_env: dict[str, str] | None = None,
             quiet: bool = False, workdir: Path | None = None) -> SoakResult:
    """The whole soak on a fresh server; returns its result (not judged)."""
    import httpx

    with tempfile.TemporaryDirectory(prefix="armtrack-soak-", dir=workdir) as tmp_name:
        tmp = Path(tmp_name)
        data_dir = tmp / "server"
        data_dir.mkdir()
        recording_path = tmp / "session.csv"
        bench_ingest.simulate_recording(session_s, recording_path)
        done = subprocess.run([sys.executable, "-m", "armtrack.server.cli", "create-user",
                               bench_ingest.THERAPIST, "--password", bench_ingest.PASSWORD,
                               "--data-dir", str(data_dir)], capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"create-user failed: {done.stderr}")
        port = bench_ingest.free_port()
        # each simulated kit starts a session every --session-s, more than a patient's
        # ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR allows: not bounded here
        server = bench_ingest.start_server(
            data_dir, port, server_cpu,
            {"ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR": "1000000", **(server_env or {})})
        base = f"http://127.0.0.1:{port}"
        try:
            http = httpx.Client(base_url=base, timeout=60)
            answer = http.post("/api/auth/token", data={"username": bench_ingest.THERAPIST,
                                                        "password": bench_ingest.PASSWORD})
            answer.raise_for_status()
            token = answer.json()["access_token"]
            http.headers["Authorization"] = f"Bearer {token}"
            patients = []
            for i in range(n):
                p = http.post("/api/patients", json={"name": f"soak {i}", "side": "right",
                                                     "height_m": 1.75})
                p.raise_for_status()
                d = http.post(f"/api/patients/{p.json()['id']}/devices",
                              json={"name": f"kit {i}"})
                d.raise_for_status()
                patients.append({"patient_id": p.json()["id"], "token": d.json()["token"]})
            return asyncio.run(soak_async(
                base=base, token=token, patients=patients, recording_path=recording_path,
                duration_s=duration_s, interval_s=interval_s, stagger_s=stagger_s,
                server_pid=server.pid, output=output, quiet=quiet))
        finally:
            bench_ingest.stop_server(server)


# -- do viewers slow ingestion? ----------------------------------------------------------------

@dataclass
class OverheadRun:
    viewers: int
    rows: int
    seconds: float
    poses_seen: int
    session: int
    server_cpu_s: float = math.nan  # the server process's CPU seconds over the round
    client_cpu_s: float = math.nan  # this process's (the kit's and the viewers')

    @property
    def rows_per_s(self) -> float:
        return self.rows / self.seconds if self.seconds > 0 else math.nan

    @property
    def rows_per_cpu_s(self) -> float:
        """Rows ingested per CPU second of the server: its rate with a core to itself."""
        return self.rows / self.server_cpu_s if self.server_cpu_s > 0 else math.nan


async def _viewers_round(ws_base: str, token: str, measured: dict, live: list[dict],
                         recording, plan, n_viewers: int, server_pid: int) -> OverheadRun:
    """``n_viewers`` ``/ws/live`` viewers, spread over the ``live`` patients (whose kits
    stream in real time all along), watch until each has had a pose; then the
    ``measured`` patient's kit streams ``recording`` as fast as it can (speed 0). The
    round's ingestion rate: its rows acked over its ``ready`` → ``bye``."""
    from armtrack.server.emulator import KitEmulator
    from websockets.asyncio.client import connect

    seen = [0]
    stop = asyncio.Event()
    first_pose = [asyncio.Event() for _ in range(n_viewers)]

    async def watch(i: int, patient_id: int) -> None:
        async with connect(f"{ws_base}/ws/live?patient={patient_id}",
                           additional_headers={"Authorization": f"Bearer {token}"},
                           open_timeout=30, max_size=2**22) as ws:
            while not stop.is_set():
                try:
                    async with asyncio.timeout(0.5):
                        text = await ws.recv()
                except TimeoutError:
                    continue
                if text.startswith('{"kind":"pose"'):
                    first_pose[i].set()
                    if not stop.is_set():
                        seen[0] += 1

    viewers = [asyncio.create_task(watch(i, live[i % len(live)]["patient_id"]))
               for i in range(n_viewers)]
    async with asyncio.timeout(60):
        for event in first_pose:
            await event.wait()
    seen[0] = 0
    kit = KitEmulator(recording, f"{ws_base}/ws/ingest", measured["token"], speed=0,
                      device="measured", ack_timeout_s=60, open_timeout_s=60)
    kit.plan = plan
    cpu_before, client_before = bench_ingest.proc_cpu_s(server_pid), time.process_time()
    stats = await kit.run()
    cpu_after, client_after = bench_ingest.proc_cpu_s(server_pid), time.process_time()
    stop.set()
    await asyncio.gather(*viewers, return_exceptions=True)
    assert stats.acked == stats.total and not stats.errors, stats.errors[:3]
    assert stats.started is not None and stats.finished is not None
    return OverheadRun(n_viewers, stats.rows_acked, stats.finished - stats.started, seen[0],
                       int(stats.session), cpu_after - cpu_before,
                       client_after - client_before)


def _wait_processed(http, session_id: int, timeout_s: float = 600.0) -> None:
    """Block until the closed session's estimates are stored (its processing would
    otherwise share the CPU with the next round)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        session = http.get(f"/api/sessions/{session_id}").raise_for_status().json()
        if session["processing_error"]:
            raise RuntimeError(f"session {session_id}: {session['processing_error']}")
        if session["processed"]:
            return
        time.sleep(0.1)
    raise TimeoutError(f"session {session_id} was not processed in {timeout_s} s")


def viewer_overhead(*, live: int = 2, viewers: int = 20, rounds: int = 4,
                    repetitions: int = 36, server_cpu: int | None = None,
                    workdir: Path | None = None) -> tuple[list[OverheadRun], float]:
    """Does watching slow ingestion? On one fresh server, ``live`` patients stream in
    real time throughout (3 sensors × 100 Hz), and in alternating rounds (0, V, V, 0, 0,
    V, V, 0, …) ``viewers`` live viewers watch them, or none; in each round one more kit
    streams a recording of ``repetitions`` elbow flexions (100 Hz) as fast as it can: the
    rate it is ingested at is what is left of the server for ingestion (each round starts
    once the previous round's session is processed). Returns the rounds and the ratio of
    the rows ingested per CPU second of the server with viewers to without, over all the
    rounds of each (1.0: no slowdown; ``viewer_cost_ratio``)."""
    import httpx
    from armtrack.estimator.recording import read_recording

    with tempfile.TemporaryDirectory(prefix="armtrack-viewers-", dir=workdir) as tmp_name:
        tmp = Path(tmp_name)
        data_dir = tmp / "server"
        data_dir.mkdir()
        measured_path, live_path = tmp / "measured.csv", tmp / "live.csv"
        bench_ingest.simulate_recording(17.0 * repetitions, measured_path)
        bench_ingest.simulate_recording(120.0, live_path)
        measured_recording, live_recording = map(read_recording, (measured_path, live_path))
        measured_plan = bench_ingest.make_cached_plan(measured_recording, 10)
        live_plan = bench_ingest.make_cached_plan(live_recording, 10)
        done = subprocess.run([sys.executable, "-m", "armtrack.server.cli", "create-user",
                               bench_ingest.THERAPIST, "--password", bench_ingest.PASSWORD,
                               "--data-dir", str(data_dir)], capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"create-user failed: {done.stderr}")
        port = bench_ingest.free_port()
        server = bench_ingest.start_server(data_dir, port, server_cpu, {})
        base = f"http://127.0.0.1:{port}"
        try:
            http = httpx.Client(base_url=base, timeout=60)
            answer = http.post("/api/auth/token", data={"username": bench_ingest.THERAPIST,
                                                        "password": bench_ingest.PASSWORD})
            answer.raise_for_status()
            token = answer.json()["access_token"]
            http.headers["Authorization"] = f"Bearer {token}"
            patients = []
            for i in range(live + 1):
                p = http.post("/api/patients", json={"name": f"viewed {i}", "side": "right",
                                                     "height_m": 1.75})
                d = http.post(f"/api/patients/{p.json()['id']}/devices", json={"name": "k"})
                patients.append({"patient_id": p.json()["id"], "token": d.json()["token"]})
            measured, live_patients = patients[0], patients[1:]

            async def all_rounds() -> list[OverheadRun]:
                from armtrack.server.emulator import KitEmulator

                ws_base = base.replace("http://", "ws://")

                async def keep_streaming(i: int, p: dict) -> None:
                    # one session of the live recording after another: on a loaded
                    # machine the rounds outlast one (120 s)
                    while True:
                        kit = KitEmulator(live_recording, f"{ws_base}/ws/ingest", p["token"],
                                          device=f"live-{i}", speed=1.0, ack_timeout_s=60)
                        kit.plan = live_plan
                        stats = await kit.run()
                        if stats.acked != stats.total or stats.errors:
                            raise RuntimeError(f"live kit {i}: {stats.acked} of {stats.total}"
                                               f" acked; {stats.errors[:3]}")

                streaming = [asyncio.create_task(keep_streaming(i, p))
                             for i, p in enumerate(live_patients)]
                try:
                    warm_up = await _viewers_round(ws_base, token, measured, live_patients,
                                                   measured_recording, measured_plan, 1,
                                                   server.pid)
                    runs = [warm_up]
                    for i in range(2 * rounds):
                        # each round starts once the last one's session is processed
                        await asyncio.to_thread(_wait_processed, http, runs[-1].session)
                        n = viewers if (i % 2 == 1) == (i // 2 % 2 == 0) else 0  # 0 V V 0 …
                        runs.append(await _viewers_round(
                            ws_base, token, measured, live_patients, measured_recording,
                            measured_plan, n, server.pid))
                        for task in streaming:
                            if task.done():  # only by an error
                                raise RuntimeError("a live kit stopped streaming") \
                                    from task.exception()
                    return runs[1:]
                finally:
                    for task in streaming:
                        task.cancel()
                    await asyncio.gather(*streaming, return_exceptions=True)

            runs = asyncio.run(all_rounds())
        finally:
            bench_ingest.stop_server(server)
    return runs, viewer_cost_ratio(runs)


def viewer_cost_ratio(runs: list[OverheadRun]) -> float:
    """Rows ingested per CPU second of the server with viewers over without, each over all
    its rounds: what the viewers leave of the server's capacity for ingestion, as on a
    server with a core of its own. Not the wall-clock rate: on a loaded 2-core machine a
    round took the server 0.55-0.88 CPU s and the client 0.24-0.46 CPU s but lasted
    1.7-6.9 s, both waiting their turn for a core, so the wall rate was the machine's load
    (0-viewer rounds alone spread 26,600-111,500 rows/s). The viewers' poses go out all
    through a round, so the longer a loaded machine makes it the more of their cost is
    counted against its rows: on a quiet machine the ratio is nearer 1."""
    def pooled(rounds: list[OverheadRun]) -> float:
        return sum(r.rows for r in rounds) / sum(r.server_cpu_s for r in rounds)
    return (pooled([r for r in runs if r.viewers])
            / pooled([r for r in runs if not r.viewers]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--patients", type=int, default=25)
    parser.add_argument("--duration", type=float, default=1800.0, help="[s] (default 1800)")
    parser.add_argument("--interval", type=float, default=10.0, help="sampling [s]")
    parser.add_argument("--session-s", type=float, default=60.0,
                        help="length of each simulated session [s] (default 60)")
    parser.add_argument("--stagger", type=float, default=5.0)
    parser.add_argument("--limit-ms", type=float, default=100.0)
    parser.add_argument("--max-slope", type=float, default=0.5,
                        help="largest RSS slope over the 2nd half [MB/min]")
    parser.add_argument("--no-pin", action="store_true")
    parser.add_argument("--output", type=Path, default=RESULTS_DIR / "soak.csv")
    parser.add_argument("--plot", type=Path, default=RESULTS_DIR / "soak.png")
    parser.add_argument("--viewers-overhead", type=int, metavar="VIEWERS", default=None,
                        help="instead of the soak: the ingestion rate of one kit streaming "
                             "unpaced beside --patients live ones, with and without "
                             "VIEWERS live viewers on them")
    args = parser.parse_args(argv)

    bench_ingest.raise_fd_limit()
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    server_cpu = None
    if not args.no_pin and len(allowed) >= 2:
        server_cpu = allowed[-1]
        bench_ingest.pin(allowed[0])
    version = bench_ingest.code_version()
    if args.viewers_overhead is not None:
        runs, ratio = viewer_overhead(live=args.patients, viewers=args.viewers_overhead,
                                      server_cpu=server_cpu)
        for r in runs:
            print(f"viewers {r.viewers:3d}: {r.rows_per_s:9,.0f} rows/s ingested, "
                  f"{r.rows_per_cpu_s:9,.0f} per server CPU s ({r.rows:,} rows in "
                  f"{r.seconds:.2f} s, {r.server_cpu_s:.2f} CPU s; {r.poses_seen:,} poses "
                  f"viewed)")
        print(f"rows per server CPU s with viewers / without: {ratio:.3f} (commit {version}; "
              f"load {bench_ingest.load_average()})")
        return 0 if ratio >= 0.9 else 1
    print(f"soak: {args.patients} patients, {args.duration:g} s, sampled every "
          f"{args.interval:g} s; sessions of {args.session_s:g} s; server "
          f"{f'on CPU {server_cpu}' if server_cpu is not None else 'not pinned'}; "
          f"commit {version}; load {bench_ingest.load_average()}", flush=True)
    result = judge(run_soak(args.patients, args.duration, interval_s=args.interval,
                            session_s=args.session_s, stagger_s=args.stagger,
                            server_cpu=server_cpu, output=args.output),
                   args.limit_ms, args.max_slope)
    title = (f"armtrack soak: {result.n} patients, {result.duration_s / 60:g} min "
             f"({version.split()[0]}); pose p99 {result.pose_p99_ms:.0f} ms, "
             f"RSS slope {result.rss_slope_mb_per_min:+.2f} MB/min, loss {result.loss}")
    plot(result, args.plot, title)
    print(f"\n{result.why}: {result.sessions} sessions, {result.rows_sent:,} rows sent, "
          f"{result.rows_stored:,} stored (loss {result.loss}); messages acked "
          f"{result.acked:,}/{result.messages:,}, refused {result.refused}, errors "
          f"{result.errors}, reconnects {result.reconnects}, kits failed "
          f"{result.kits_failed}, viewer drops {result.viewer_drops}")
    print(f"poses {result.poses:,}: p50 {result.pose_p50_ms:.1f} ms, p99 "
          f"{result.pose_p99_ms:.1f} ms, max {result.pose_max_ms:.0f} ms; ack p99 "
          f"{result.ack_p99_ms:.0f} ms; server CPU median {result.server_cpu_pct:.0f} %")
    print(f"RSS {result.rss_first_mb:.0f} → {result.rss_last_mb:.0f} MB (max "
          f"{result.rss_max_mb:.0f}); slope over the 2nd half "
          f"{result.rss_slope_mb_per_min:+.3f} MB/min; load {bench_ingest.load_average()}")
    for problem in result.problems_seen[:10]:
        print(f"  problem: {problem}")
    print(f"written: {args.output}, {args.plot}")
    return 0 if result.holds else 1


if __name__ == "__main__":
    raise SystemExit(main())
