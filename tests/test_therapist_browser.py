"""The therapist's day in a real browser (Debian's headless chromium, Playwright) against
a real server fed by the kit emulator at real pace: the live page names the exercise and
counts its repetitions as they happen, then follows the patient to their next session by
itself, keeping the day's sessions; the patient page's tools (targets, progress charts,
editing the record, the data export, closing an interrupted session, erasing the
patient); no page wider than the screen at 390 and 1366 px. Screenshots are saved
(``ARMTRACK_SCREENSHOTS``) to be looked at."""

from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import replace

import pytest
import test_pages_browser
from test_pages_browser import KitThread, sign_in, sync_api

# the browser fixtures of test_pages_browser (one chromium per module)
browser_context = test_pages_browser.browser_context
page = test_pages_browser.page
shots = test_pages_browser.shots

pytestmark = pytest.mark.slow

WIDTHS = (390, 1366)


def short_exercise(name: str, repetitions: int = 3, seed: int = 0):
    """Calibration poses, then ``repetitions`` of ``name`` marked as an exercise."""
    from armtrack.estimator.recording import Mark
    from armtrack.estimator.simulation import SimulationConfig, simulate
    from armtrack.estimator.simulation.scenarios import EXERCISE_START_S

    recording = simulate(SimulationConfig(exercise=name, repetitions=repetitions,
                                          seed=seed)).recording
    end = min(float(s.t[-1]) for s in recording.sensors.values()) - 1.0
    return dataclasses.replace(recording, marks=(
        Mark(EXERCISE_START_S - 0.5, f"exercise:{name}"), Mark(end, f"end:exercise:{name}")))


def no_horizontal_overflow(page, where: str) -> None:
    width = page.evaluate("document.documentElement.scrollWidth")
    inner = page.evaluate("window.innerWidth")
    print(f"{where}: page {width} px wide in a {inner} px window")
    assert width <= inner, f"{where}: the page is {width} px wide in a {inner} px window"


def test_the_live_page_counts_and_follows_the_patient(module_server, page, shots):
    api = module_server.client("alice")
    patient = api.patient("Follow Me")
    device = api.device(patient["id"])
    page.set_viewport_size({"width": 1366, "height": 900})
    sign_in(page, module_server.url)
    first_kit = KitThread(short_exercise("elbow_flexion", repetitions=10),
                          module_server.ws_url, device["token"])
    deadline = time.monotonic() + 30
    live = None
    while time.monotonic() < deadline:
        live = api.http.get(f"/api/patients/{patient['id']}/live").json()["session"]
        if live:
            break
        time.sleep(0.3)
    assert live, "the kit's stream did not start"
    page.goto(f"{module_server.url}/sessions/{live['id']}")
    name = page.locator("#exercise-name")
    sync_api.expect(name).to_have_text("Elbow flexion", timeout=60_000)
    reps = page.locator("#exercise-reps")
    sync_api.expect(reps).to_have_text(re.compile(r"^[1-9]\d* repetitions?$"), timeout=60_000)
    no_horizontal_overflow(page, "live page at 1366")
    seen = []  # the count as it grows, until the session ends and the box goes
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        text = page.evaluate("document.getElementById('exercise-reps')?.textContent ?? null")
        if text is None:
            break  # the session ended
        if text and (not seen or seen[-1] != text):
            seen.append(text)
        time.sleep(0.3)
    first_kit.thread.join(30)
    counts = [int(t.split()[0]) for t in seen]
    print(f"live repetitions as shown: {seen}")
    assert counts == sorted(counts) and counts[-1] >= 2, seen  # counted as they happen

    # the patient starts the next exercise: the page moves to it by itself
    second_kit = KitThread(short_exercise("shoulder_flexion", repetitions=10, seed=1),
                           module_server.ws_url,
                           device["token"])
    try:
        sync_api.expect(page.locator("#next-session")).to_be_visible(timeout=60_000)
        page.wait_for_url(re.compile(r".*/sessions/\d+$"), timeout=30_000)
        page.wait_for_function(f"location.pathname !== '/sessions/{live['id']}'",
                               timeout=30_000)
        new_id = int(page.url.rsplit("/", 1)[1])
        assert new_id > live["id"]
        sync_api.expect(page.locator("#day-history .day-session")).to_have_count(2)
        sync_api.expect(page.locator("#day-history .current")).to_have_attribute(
            "data-session", str(new_id))
        sync_api.expect(page.locator("#exercise-name")).to_have_text("Shoulder flexion",
                                                                    timeout=60_000)
        page.screenshot(path=str(shots / "live-exercise-1366.png"), full_page=True,
                        timeout=90_000)
        page.set_viewport_size({"width": 390, "height": 844})
        page.screenshot(path=str(shots / "live-follow-390.png"), full_page=True, timeout=90_000)
        no_horizontal_overflow(page, "live page at 390")
    finally:
        second_kit.cut()
    # the first session's report counts what the page counted (the page may miss the
    # last one, completed as the kit said bye)
    report = api.http.get(f"/api/sessions/{live['id']}/report")
    assert report.status_code == 200, report.text
    total = max(a["repetitions"] for a in report.json()["exercises"][0]["angles"])
    print(f"report: {total} repetitions; live page: {counts[-1]}")
    assert total - 1 <= counts[-1] <= total


def _upload(api, patient_id, recordings_dir, name, start_time):
    from armtrack.estimator.recording import format_recording, read_recording

    recording = read_recording(recordings_dir / f"{name}.csv")
    recording = replace(recording, metadata={**recording.metadata, "start_time": start_time})
    answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                           files={"file": (f"{name}.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    return answer.json()


def test_the_dashboard_reaches_targets_progress_record_and_erasure(
        module_server, page, shots, recordings_dir):
    api = module_server.client("alice")
    patient = api.http.post("/api/patients", json={
        "name": "Dashboard Patient", "side": "right", "height_m": 1.75,
        "clinic_number": "A-17", "date_of_birth": "1971-03-02"}).json()
    pid = patient["id"]
    api.http.put(f"/api/patients/{pid}/targets/elbow_flexion",
                 json={"min_deg": 0, "max_deg": 115, "note": "week 1"})
    _upload(api, pid, recordings_dir, "elbow_6axis", "2026-11-24T09:30:00+01:00")
    _upload(api, pid, recordings_dir, "elbow_flexion", "2026-12-01T09:41:00+01:00")
    # an interrupted stream to close from the page
    kit = KitThread(short_exercise("elbow_flexion", repetitions=8),
                    module_server.ws_url, api.device(pid)["token"])
    time.sleep(4)
    kit.cut()

    sign_in(page, module_server.url)
    for width in WIDTHS:
        page.set_viewport_size({"width": width, "height": 900})
        page.goto(f"{module_server.url}/patients")
        row = page.locator("#patients tbody tr", has_text="Dashboard Patient")
        sync_api.expect(row.locator(".last-session")).not_to_contain_text("none yet")
        no_horizontal_overflow(page, f"patients at {width}")
        page.screenshot(path=str(shots / f"patients-{width}.png"), full_page=True, timeout=90_000)
        page.goto(f"{module_server.url}/patients/{pid}")
        sync_api.expect(page.locator("#progress-card .session-bar")).to_have_count(3)
        sync_api.expect(page.locator("#facts")).to_contain_text("clinic no. A-17")
        no_horizontal_overflow(page, f"patient at {width}")
        page.screenshot(path=str(shots / f"patient-tools-{width}.png"), full_page=True,
                        timeout=90_000)

    page.set_viewport_size({"width": 1366, "height": 900})
    # closing the interrupted session
    close = page.locator("#interrupted-card .close-session")
    sync_api.expect(close).to_have_count(1, timeout=30_000)
    close.click()
    sync_api.expect(page.locator("#interrupted-card")).to_have_count(0, timeout=30_000)
    # setting a target from the page
    page.select_option("#target-angle", "shoulder_flexion")
    page.fill("#target-min", "0")
    page.fill("#target-max", "150")
    page.fill("#target-note", "reach the shelf")
    page.click("#target-form button[type=submit]")
    sync_api.expect(page.locator('#targets-table tr[data-angle="shoulder_flexion"]')
                    ).to_contain_text("reach the shelf")
    assert [t["angle"] for t in api.http.get(f"/api/patients/{pid}/targets").json()] == [
        "elbow_flexion", "shoulder_flexion"]
    # the progress chart of the elbow: today's target line is drawn
    sync_api.expect(page.locator('#progress-card [data-angle="elbow_flexion"] .today')
                    ).to_contain_text("today's target")
    page.locator("#progress-card").screenshot(path=str(shots / "progress-1366.png"), timeout=90_000)
    # editing the record
    page.fill("#edit-clinic_number", "A-18")
    page.click("#edit-patient button[type=submit]")
    sync_api.expect(page.locator("#facts")).to_contain_text("clinic no. A-18")
    assert api.http.get(f"/api/patients/{pid}").json()["clinic_number"] == "A-18"
    # the export
    with page.expect_download() as download:
        page.click("#export-patient")
    assert download.value.suggested_filename == f"patient-{pid}.zip"
    # erasing: a wrong name erases nothing, the right one erases
    page.once("dialog", lambda d: d.accept("someone else"))
    page.click("#erase-patient")
    sync_api.expect(page.locator(".error")).to_contain_text("nothing was erased")
    page.once("dialog", lambda d: d.accept("Dashboard Patient"))
    page.click("#erase-patient")
    page.wait_for_url(re.compile(r".*/patients$"))
    assert api.http.get(f"/api/patients/{pid}").status_code == 404
