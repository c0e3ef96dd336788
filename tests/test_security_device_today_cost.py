"""What a kit's link costs the server at each opening of the phone kit (attack13).

``GET /api/device/today`` (the phone asks it at every page load, before its welcome)
carries the patient's ``recent`` sessions (dd66ede): their numbers come from each
session's report, so up to six of the patient's latest estimated sessions had their
report built, whether or not a kit had marked an exercise in them (a session without
marks tells nothing). Found on a real server: a patient with twelve uploaded 450k-row
sessions (no marks), the server just restarted: the first ``today`` took 18.9 s of the
server (the phone showing nothing meanwhile), 0.05 s once cached; it costs that again
whenever the reports' cache lets them go. Now only sessions with an exercise mark are
looked at."""

from __future__ import annotations

import time

import httpx
from server_support import server_fixture
from test_security_report_cost import tiled

server = server_fixture("device_today_cost", "alice")


def test_a_kits_today_builds_no_report_of_a_session_without_marks(server, recordings_dir,
                                                                   tmp_path):
    api = server.client("alice")
    patient = api.patient("Long Uploads")
    path = tiled(recordings_dir / "elbow_6axis_long.csv", 3, tmp_path / "long.csv")
    for _ in range(2):
        with path.open("rb") as f:
            answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                                   files={"file": (path.name, f, "text/csv")}, timeout=900)
        assert answer.status_code == 201, answer.text[:300]
    kit = {"Authorization": f"Bearer {api.device(patient['id'], 'phone')['token']}"}
    server.stop()
    server.start()  # the reports' cache is empty, as after any restart or eviction
    took = []
    for _ in range(2):
        began = time.monotonic()
        today = httpx.get(f"{server.url}/api/device/today", headers=kit, timeout=900)
        took.append(time.monotonic() - began)
        assert today.status_code == 200, today.text
        assert today.json()["recent"] == []  # nothing marked: nothing to tell
    print(f"\nthe kit's today with 2 unmarked {answer.json()['samples']}-row sessions: "
          f"{took[0]:.2f} s first, {took[1]:.2f} s again")
    assert took[0] < 1.0, f"the first today took {took[0]:.1f} s"
