"""Load, in CI: a 60-second version of ``bench/soak.py`` (the 30-minute soak runs from
``bench/``), and 20 live viewers against ingestion (``bench/soak.py --viewers-overhead``).
Both run a real ``armtrack serve`` subprocess, not pinned (CI's cores are unknown)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import soak  # bench/soak.py

PATIENTS = 5  # a modest N that holds on a shared 2-core CI machine (25 held for 30 min)


def test_a_one_minute_soak_loses_nothing_keeps_memory_bounded_and_poses_fast(tmp_path):
    """5 patients, each a kit in real time (3 sensors × 100 Hz, one ~17 s session after
    another) and a /ws/live viewer, for 60 s, sampled every 5 s: zero loss (every session's
    stored samples = the rows sent, every message acked, nothing refused, no error, no
    reconnect); pose latency p99 < 100 ms; RSS bounded: after the first 20 s (imports,
    numba, the first sessions' processing), the least-squares slope is under 20 MB/min and
    RSS ends within 40 MB of its value then (a leak of a session's buffers, ~3 MB each,
    over the ~15 sessions that follow would break both)."""
    result = soak.run_soak(PATIENTS, 60.0, interval_s=5.0, session_s=10.0, stagger_s=2.0,
                           quiet=True, workdir=tmp_path, output=tmp_path / "soak.csv")
    print(f"soak 60 s: {result.sessions} sessions, {result.rows_sent:,} rows sent, "
          f"{result.rows_stored:,} stored; poses {result.poses:,}, p99 "
          f"{result.pose_p99_ms:.1f} ms; RSS {result.rss_first_mb:.0f} → "
          f"{result.rss_last_mb:.0f} MB; problems {result.problems_seen[:3]}")
    assert result.sessions >= 2 * PATIENTS
    assert result.loss == 0 and result.rows_sent == result.rows_stored > 0
    assert result.acked == result.messages and result.refused == result.errors == 0
    assert result.kits_failed == result.reconnects == result.viewer_drops == 0
    assert result.poses > 1000 and result.pose_p99_ms < 100.0
    rows = [r for r in result.rows if r["elapsed_s"] >= 20.0 and r["rss_mb"] > 0]
    t = np.array([r["elapsed_s"] for r in rows]) / 60.0
    rss = np.array([r["rss_mb"] for r in rows])
    slope = np.polyfit(t, rss, 1)[0]
    print(f"RSS after 20 s: {rss.round(1).tolist()} MB; slope {slope:+.2f} MB/min")
    assert slope < 20.0 and rss.max() - rss[0] < 40.0


def test_20_live_viewers_do_not_slow_ingestion_by_more_than_10_percent(tmp_path):
    """Two patients stream in real time all along; in alternating rounds (0, 20, 20, 0, 0,
    20, 20, 0 viewers) 20 /ws/live viewers watch them (10 each, ~10 poses/s each), or none,
    while a third kit streams 36 elbow flexions (~180,000 rows, 1–2 s) as fast as it can,
    each round once the last one's session is processed. With viewers the server ingests
    at least 90 % of the rows per CPU second it does without (over the four rounds of
    each; ``soak.viewer_cost_ratio``: the wall-clock rate is the test client's, which
    runs the kit and the 20 viewers, not the server's)."""
    runs, ratio = soak.viewer_overhead(live=2, viewers=20, rounds=4, repetitions=36,
                                       workdir=tmp_path)
    for r in runs:
        print(f"viewers {r.viewers:2d}: {r.rows_per_s:9,.0f} rows/s, "
              f"{r.rows_per_cpu_s:9,.0f} rows per server CPU s ({r.server_cpu_s:.2f} s in "
              f"{r.seconds:.2f} s, the client {r.client_cpu_s:.2f} CPU s; {r.poses_seen} "
              f"poses viewed)")
    wall = (max(r.rows_per_s for r in runs if r.viewers)
            / max(r.rows_per_s for r in runs if not r.viewers))
    print(f"rows per server CPU s with viewers / without: {ratio:.3f} (the client's wall "
          f"rate, best with / best without: {wall:.3f})")
    assert all(r.poses_seen > 0 for r in runs if r.viewers)
    assert ratio >= 0.90
