"""A session's report costs in proportion to its length, on a real server: a kit (or a
therapist's upload) cannot make a session whose report holds the server for minutes.

The finding: each exercise's range of motion and each repetition's smoothness masked the
whole session's arrays (``select`` over every sample, once per exercise and once per
repetition), so a report cost the session's length times its exercises and repetitions.
A 1.75-hour session (elbow_6axis_long tiled 21 times: 1.89 million rows, 105 exercises,
2,392 repetitions) took 177 s of the server for its first summary (70 s alone in one
process), on a sync route: a kit may upload 20 such sessions an hour."""

from __future__ import annotations

import time
from pathlib import Path

from server_support import server_fixture

server = server_fixture("report_cost", "alice")


def tiled(source: Path, copies: int, out: Path) -> Path:
    """``source`` (a recording) played ``copies`` times in a row, its times shifted."""
    lines = source.read_text().splitlines()
    body = next(i for i, line in enumerate(lines) if line.startswith("t,")) + 1
    span = float(lines[-1].split(",", 1)[0]) + 0.01
    with out.open("w") as f:
        f.write("\n".join(lines[:body]) + "\n")
        for k in range(copies):
            for line in lines[body:]:
                t, rest = line.split(",", 1)
                f.write(f"{float(t) + k * span:.4f},{rest}\n")
    return out


def test_a_long_sessions_report_costs_in_proportion_to_its_length(server, recordings_dir,
                                                                 tmp_path):
    api = server.client("alice")
    source = recordings_dir / "elbow_6axis_long.csv"
    took = {}
    for copies in (1, 8):
        patient = api.patient(name=f"Long {copies}")
        path = tiled(source, copies, tmp_path / f"long{copies}.csv")
        with path.open("rb") as f:
            answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                                   files={"file": (path.name, f, "text/csv")}, timeout=900)
        assert answer.status_code == 201, answer.text[:300]
        session = answer.json()
        assert session["processing_error"] is None, session
        start = time.monotonic()
        summary = api.http.get(f"/api/sessions/{session['id']}/summary", timeout=900)
        took[copies] = time.monotonic() - start
        assert summary.status_code == 200, summary.text[:300]
        print(f"\n{copies} copies: {session['samples']} samples, "
              f"{len(summary.json()['exercises'])} exercises, summary {took[copies]:.2f} s")
    ratio = took[8] / took[1]
    print(f"8 copies cost {ratio:.1f}x one copy's report (8x: in proportion)")
    assert ratio < 20, f"8x the session cost {ratio:.0f}x the report"
