"""A program beside sessions it does not count: found on a therapist's walk, the program
card said "Bend the elbow · not done yet" and adherence 0 / 4 under a session list showing
"Elbow flexion × 5" the same day — the sensor kit had neither followed the program nor
marked its exercises (docs/programs.md), and the page did not say so. Now the adherence
answer counts such sessions and the card says how many and why. A real server: one
session streamed by ``armtrack stream`` (no program, no marks: not counted) and one
uploaded recording marking the exercise (counted); the patient page at 1280 px."""

from __future__ import annotations

import subprocess
import sys
from datetime import UTC, datetime

from armtrack.estimator.simulation import SimulationConfig, simulate
from browser_helpers import need_browser, page_at, sign_in_as
from server_support import server_fixture

sync_api = need_browser()

server = server_fixture("program-uncounted", "alice")


def marked_recording(path) -> bytes:
    """A simulated elbow-flexion session with its exercise marked (recording.md ``marks``)."""
    from armtrack.estimator.recording import write_recording

    sim = simulate(SimulationConfig(exercise="elbow_flexion", seed=4))
    write_recording(sim.recording, path)
    text = path.read_text()
    return text.replace("# rate_hz:", "# marks: 9.0 exercise:elbow_flexion; "
                        f"{sim.recording.duration - 0.5:.1f} end:exercise:elbow_flexion\n"
                        "# rate_hz:", 1).encode()


def test_sessions_a_program_does_not_count_are_said_on_its_card(server, tmp_path):
    api = server.client("alice")
    patient = api.patient("Uncounted", side="right")
    today = datetime.now(UTC).date().isoformat()  # the clinic's zone is UTC
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "Elbow", "start_date": today, "exercises": [
            {"exercise": "elbow_flexion", "sets": 1, "repetitions": 5, "days_per_week": 5}]})
    assert made.status_code == 201, made.text
    program_id = made.json()["id"]
    token = api.device(patient["id"], "sensor kit")["token"]
    streamed = subprocess.run(
        [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise", "elbow_flexion",
         "--url", server.ws_url, "--token", token, "--speed", "0", "--quiet"],
        capture_output=True, text=True, timeout=300)
    assert streamed.returncode == 0, streamed.stderr
    uploaded = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                             files={"file": ("home.csv", marked_recording(tmp_path / "m.csv"),
                                             "text/csv")})
    assert uploaded.status_code == 201, uploaded.text
    for s in api.http.get(f"/api/patients/{patient['id']}/sessions").json():
        api.wait_processed(s["id"], timeout=180)

    adherence = api.http.get(f"/api/programs/{program_id}/adherence").json()
    print(f"\ncounted {[s['session_id'] for s in adherence['sessions']]}, "
          f"not counted: {adherence.get('uncounted_sessions')}")
    assert [s["session_id"] for s in adherence["sessions"]] == [uploaded.json()["id"]]
    assert adherence["uncounted_sessions"] == 1

    with page_at(1280) as page:
        sign_in_as(page, server.url, "alice")
        page.goto(f"{server.url}/patients/{patient['id']}")
        note = page.locator(f'[data-program="{program_id}"] .uncounted')
        sync_api.expect(note).to_be_visible(timeout=30_000)
        said = note.inner_text()
        print(said)
        page.locator(f'[data-program="{program_id}"]').screenshot(
            path=str(tmp_path / "program-card.png"))
    assert said.startswith("1 session of this patient during this program is not counted")
    assert "did not follow this program" in said
