"""A patient's progress costs little once read, however many sessions the patient has, on
a real server.

The finding (attack10): ``GET /api/patients/{id}/progress`` (and progress.csv) built every
session's report, and the report cache holds 64: past 64 sessions every read missed them
all. One patient with 90 uploaded sessions took 4.6 / 6.9 / 5.0 s per read, linear in the
sessions (two sessions a day: 45 days), on every view of the therapist's patient page. Each
session's progress row is now kept by what identifies its estimates; the targets are
applied at each read. Sessions here are copies of one upload, made by SQL, spread over
days."""

from __future__ import annotations

import time
from datetime import datetime, timedelta

import pytest
from server_support import server_fixture
from test_export_memory import copy_session

server = server_fixture("progress_cost", "alice")

SESSIONS = 72  # past the report cache's 64
HOURS_APART = 12


def stored(moment: datetime) -> str:
    """A moment as SQLite's rows hold it (SQLAlchemy's format, microseconds always)."""
    return moment.strftime("%Y-%m-%d %H:%M:%S.%f")


def timed_progress(api, patient_id: int) -> tuple[float, dict]:
    began = time.perf_counter()
    answer = api.http.get(f"/api/patients/{patient_id}/progress", timeout=300)
    took = time.perf_counter() - began
    assert answer.status_code == 200, answer.text[:300]
    return took, answer.json()


@pytest.fixture(scope="module")
def many(server, recordings_dir) -> tuple[int, list[int]]:
    """A patient with SESSIONS sessions (one upload and its copies), HOURS_APART apart,
    oldest first; (patient id, session ids)."""
    api = server.client("alice")
    patient = api.patient("Many sessions")
    path = recordings_dir / "elbow_flexion.csv"
    with path.open("rb") as f:
        answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                               files={"file": (path.name, f, "text/csv")}, timeout=300)
    assert answer.status_code == 201, answer.text[:300]
    first = answer.json()["id"]
    assert not api.wait_processed(first, 300)["processing_error"]
    ids = [first] + [copy_session(server, first) for _ in range(SESSIONS - 1)]
    started = datetime.fromisoformat(str(server.sql(
        "SELECT started_at FROM sessions WHERE id = :id", id=first)[0][0]))
    for k, session_id in enumerate(ids):  # oldest first, the upload the newest
        server.sql("UPDATE sessions SET started_at = :at WHERE id = :id", id=session_id,
                   at=stored(started - timedelta(hours=HOURS_APART * (SESSIONS - 1 - k))))
    return patient["id"], ids


def test_a_second_read_of_a_long_progress_builds_no_report_again(server, many):
    api = server.client("alice")
    patient_id, ids = many
    cold, first = timed_progress(api, patient_id)
    warm, second = timed_progress(api, patient_id)
    print(f"progress of {len(ids)} sessions: first read {cold:.2f} s, second {warm:.2f} s "
          f"({cold / warm:.0f}×)")
    assert [s["session_id"] for s in first["sessions"]] == ids
    assert all(s["processed"] for s in first["sessions"])
    assert second == first  # the same answer as the one built from the reports
    assert warm < cold / 4, (cold, warm)


def test_kept_progress_follows_the_targets_the_estimates_and_erasure(server, many):
    """Nothing stale: a target set (moved back so it was in force for the later half of
    the sessions) is applied to those sessions' rows, as their own reports show it; a
    session whose estimates went (as while reprocessed) is listed unprocessed; an erased
    session is gone."""
    api = server.client("alice")
    patient_id, ids = many
    timed_progress(api, patient_id)  # rows kept
    put = api.http.put(f"/api/patients/{patient_id}/targets/elbow_flexion",
                       json={"min_deg": 0, "max_deg": 100})
    assert put.status_code == 200, put.text
    middle = datetime.fromisoformat(str(server.sql(
        "SELECT started_at FROM sessions WHERE id = :id", id=ids[SESSIONS // 2])[0][0]))
    server.sql("UPDATE patient_target_versions SET set_at = :at WHERE patient_id = :p",
               at=stored(middle - timedelta(minutes=1)), p=patient_id)
    took, progress = timed_progress(api, patient_id)
    rows = {s["session_id"]: s for s in progress["sessions"]}
    for k in (0, SESSIONS // 2 - 1, SESSIONS // 2, SESSIONS - 1):
        report = api.http.get(f"/api/sessions/{ids[k]}/report").json()
        assert rows[ids[k]]["rom"] == report["rom"], k
    reached = [rows[i]["rom"]["elbow_flexion"]["target_max"] for i in ids]
    assert reached == [None] * (SESSIONS // 2) + [100] * (SESSIONS - SESSIONS // 2)
    print(f"after a target: {took:.2f} s; elbow at "
          f"{rows[ids[-1]]['rom']['elbow_flexion']['percent_of_target']} % of target")

    gone, erased = ids[3], ids[4]
    server.sql("DELETE FROM estimate_blocks WHERE session_id = :id", id=gone)
    server.sql("UPDATE sessions SET estimate_columns = NULL, estimator = NULL WHERE id = :id",
               id=gone)
    assert api.http.delete(f"/api/sessions/{erased}").status_code == 204
    _, progress = timed_progress(api, patient_id)
    rows = {s["session_id"]: s for s in progress["sessions"]}
    assert erased not in rows and len(rows) == SESSIONS - 1
    assert not rows[gone]["processed"] and rows[gone]["rom"] == {}
    assert rows[ids[5]]["processed"] and rows[ids[5]]["rom"]
    assert progress["trend"]["elbow_flexion"]["sessions"] == SESSIONS - 2
