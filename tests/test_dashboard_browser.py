"""The patient page's tools in a real browser (Debian's headless chromium, Playwright)
against a real server, each action done through the page and its result checked through
the API: the progress charts (one bar per estimated session and joint, today's target
drawn), setting a target, editing the patient's record, the patient-data export (a real
zip), closing an interrupted session (a kit's stream cut at real pace), and erasing the
patient (a wrong name erases nothing). Uploading through the import dialog is covered by
``tests/test_import_browser.py``. No page wider than the screen at 390 and 1366 px.

Every wait is on a condition with a generous timeout (the machine may be busy).
Screenshots go to ``ARMTRACK_SCREENSHOTS`` (else a temporary folder, printed)."""

from __future__ import annotations

import io
import re
import time
import zipfile
from dataclasses import replace

import pytest
import test_pages_browser
from browser_helpers import sign_in_as
from test_live_motion import short_exercise
from test_pages_browser import KitThread, sync_api

# the browser fixtures of test_pages_browser (one chromium per module)
browser_context = test_pages_browser.browser_context
page = test_pages_browser.page
shots = test_pages_browser.shots

pytestmark = pytest.mark.slow

WIDTHS = (390, 1366)
#: How long a page element may take to show on a busy machine [ms].
SLOW_MS = 90_000
NAME = "Dashboard Patient"


def no_horizontal_overflow(page, where: str) -> None:
    width = page.evaluate("document.documentElement.scrollWidth")
    inner = page.evaluate("window.innerWidth")
    print(f"{where}: page {width} px wide in a {inner} px window")
    assert width <= inner, f"{where}: the page is {width} px wide in a {inner} px window"


def upload(api, patient_id, recordings_dir, name, start_time) -> dict:
    """Upload a recording with ``start_time`` and wait until it is estimated."""
    from armtrack.estimator.recording import format_recording, read_recording

    recording = read_recording(recordings_dir / f"{name}.csv")
    recording = replace(recording, metadata={**recording.metadata, "start_time": start_time})
    answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                           files={"file": (f"{name}.csv", format_recording(recording))})
    assert answer.status_code == 201, answer.text
    session = api.wait_processed(answer.json()["id"], timeout=300)
    assert session["processed"], session["processing_error"]
    return session


def wait_for(condition, what: str, timeout: float = 120.0):
    """Poll ``condition()`` until it returns something true; fail naming ``what``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"{what} did not happen within {timeout:.0f} s")


def interrupted_stream(api, patient_id, ws_url) -> int:
    """A kit streams at real pace and its link dies mid-session: the session's id."""
    kit = KitThread(short_exercise("elbow_flexion", 8), ws_url, api.device(patient_id)["token"])
    try:
        live = wait_for(lambda: api.http.get(f"/api/patients/{patient_id}/live").json()["session"],
                        "the kit's stream starting")
        # cut mid-exercise, after three repetitions: there is a range to estimate
        wait_for(lambda: (api.http.get(f"/api/patients/{patient_id}/live").json()
                          .get("exercise") or {}).get("repetitions", 0) >= 3,
                 "three repetitions counted live", timeout=180)
    finally:
        kit.cut()
    wait_for(lambda: api.session(live["id"])["status"] == "interrupted",
             "the cut stream's session marked interrupted")
    return live["id"]


def test_the_dashboard_reaches_progress_targets_record_interrupted_and_erasure(
        module_server, page, shots, recordings_dir):
    api = module_server.client("alice")
    answer = api.http.post("/api/patients", json={
        "name": NAME, "side": "right", "height_m": 1.75,
        "clinic_number": "A-17", "date_of_birth": "1971-03-02"})
    assert answer.status_code == 201, answer.text
    pid = answer.json()["id"]
    answer = api.http.put(f"/api/patients/{pid}/targets/elbow_flexion",
                          json={"min_deg": 0, "max_deg": 115, "note": "week 1"})
    assert answer.status_code == 200, answer.text
    # two estimated sessions a week apart (the page draws progress once, from the
    # estimates stored when it loads: they must be there first)
    upload(api, pid, recordings_dir, "elbow_6axis", "2026-11-24T09:30:00+01:00")
    upload(api, pid, recordings_dir, "elbow_flexion", "2026-12-01T09:41:00+01:00")
    interrupted_id = interrupted_stream(api, pid, module_server.ws_url)
    progress = api.http.get(f"/api/patients/{pid}/progress").json()
    bars = sum(len(s["rom"]) for s in progress["sessions"])
    elbow_bars = sum("elbow_flexion" in s["rom"] for s in progress["sessions"])
    print("progress:", [(s["session_id"], s["status"], sorted(s["rom"]))
                        for s in progress["sessions"]])
    assert elbow_bars >= 2  # the two uploads at least (the cut stream's ranges so far too)

    sign_in_as(page, module_server.url, "alice")
    for width in WIDTHS:
        page.set_viewport_size({"width": width, "height": 900})
        page.goto(f"{module_server.url}/patients")
        row = page.locator("#patients tbody tr", has_text=NAME)
        sync_api.expect(row.locator(".last-session")).not_to_contain_text("none yet",
                                                                          timeout=SLOW_MS)
        no_horizontal_overflow(page, f"patients at {width}")
        page.goto(f"{module_server.url}/patients/{pid}")
        sync_api.expect(page.locator("#facts")).to_contain_text("clinic no. A-17",
                                                                timeout=SLOW_MS)
        # one bar per estimated session and joint, as the API gives them
        sync_api.expect(page.locator("#progress-card .session-bar")).to_have_count(
            bars, timeout=SLOW_MS)
        elbow = page.locator('#progress-card .progress-angle[data-angle="elbow_flexion"]')
        sync_api.expect(elbow.locator(".session-bar")).to_have_count(elbow_bars)
        sync_api.expect(elbow.locator(".today")).to_have_text("today's target 0…115°")
        sync_api.expect(page.locator("#interrupted-card .close-session")).to_have_count(
            1, timeout=SLOW_MS)
        # its row says what it takes to estimate it: an interrupted session is estimated
        # only once closed (before: "when estimated", "when finished")
        row = page.locator(f'#sessions tr[data-session="{interrupted_id}"]')
        sync_api.expect(row).to_contain_text("close it to estimate", timeout=SLOW_MS)
        assert "when " not in row.inner_text(), row.inner_text()
        no_horizontal_overflow(page, f"patient at {width}")
        elbow.scroll_into_view_if_needed()
        page.locator("#progress-card").screenshot(path=str(shots / f"progress-{width}.png"),
                                                  timeout=SLOW_MS)
        page.screenshot(path=str(shots / f"patient-tools-{width}.png"), full_page=True,
                        timeout=SLOW_MS)
        box = page.locator("#progress-card svg.progress-chart").first.bounding_box()
        print(f"progress chart at {width}: {box['width']:.0f} x {box['height']:.0f} px")
        assert box["width"] <= width and box["height"] > 50
        # its axis text readable on a phone too: drawn at the shown width, not scaled down
        tick = page.locator("#progress-card svg.progress-chart text.tick").first.bounding_box()
        print(f"axis label at {width}: {tick['height']:.1f} px high")
        assert tick["height"] >= 9, f"axis labels {tick['height']:.1f} px high at {width} px"

    page.set_viewport_size({"width": 1366, "height": 900})

    # closing the interrupted session: closed and estimated
    page.locator(f'#interrupted-card [data-session="{interrupted_id}"] .close-session').click()
    sync_api.expect(page.locator("#interrupted-card")).to_have_count(0, timeout=SLOW_MS)
    assert api.session(interrupted_id)["status"] == "closed"
    closed = api.wait_processed(interrupted_id, timeout=300)
    assert closed["processed"], closed["processing_error"]
    # its estimate joins the elbow's chart without reloading the page
    rom = {s["session_id"]: s["rom"] for s in
           api.http.get(f"/api/patients/{pid}/progress").json()["sessions"]}
    print(f"closed session {interrupted_id}: ranges of {sorted(rom[interrupted_id])}")
    assert "elbow_flexion" in rom[interrupted_id]
    sync_api.expect(page.locator('#progress-card [data-angle="elbow_flexion"] .session-bar')
                    ).to_have_count(elbow_bars + 1, timeout=SLOW_MS)

    # setting a target from the page: in the table, through the API, and on the chart
    page.select_option("#target-angle", "shoulder_flexion")
    page.fill("#target-min", "0")
    page.fill("#target-max", "150")
    page.fill("#target-note", "reach the shelf")
    page.click("#target-form button[type=submit]")
    sync_api.expect(page.locator('#targets-table tr[data-angle="shoulder_flexion"]')
                    ).to_contain_text("reach the shelf", timeout=SLOW_MS)
    targets = {t["angle"]: t for t in api.http.get(f"/api/patients/{pid}/targets").json()}
    assert sorted(targets) == ["elbow_flexion", "shoulder_flexion"]
    assert (targets["shoulder_flexion"]["min_deg"], targets["shoulder_flexion"]["max_deg"],
            targets["shoulder_flexion"]["note"]) == (0, 150, "reach the shelf")
    # the elbow's target changed from the page too: the chart redraws today's line
    page.select_option("#target-angle", "elbow_flexion")
    page.fill("#target-min", "5")
    page.fill("#target-max", "125")
    page.click("#target-form button[type=submit]")
    sync_api.expect(page.locator('#progress-card [data-angle="elbow_flexion"] .today')
                    ).to_have_text("today's target 5…125°", timeout=SLOW_MS)
    elbow_now = api.http.get(f"/api/patients/{pid}/targets").json()
    assert [(t["min_deg"], t["max_deg"]) for t in elbow_now
            if t["angle"] == "elbow_flexion"] == [(5, 125)]

    # editing the record
    page.fill("#edit-clinic_number", "A-18")
    page.fill("#edit-height_m", "1.78")
    page.click("#edit-patient button[type=submit]")
    sync_api.expect(page.locator("#facts")).to_contain_text("clinic no. A-18", timeout=SLOW_MS)
    record = api.http.get(f"/api/patients/{pid}").json()
    assert (record["clinic_number"], record["height_m"], record["date_of_birth"]) == (
        "A-18", 1.78, "1971-03-02")

    # the export: a zip holding the patient's data
    with page.expect_download(timeout=SLOW_MS) as download:
        page.click("#export-patient")
    assert download.value.suggested_filename == f"patient-{pid}.zip"
    with zipfile.ZipFile(io.BytesIO(open(download.value.path(), "rb").read())) as archive:
        names = archive.namelist()
        print(f"export: {len(names)} files: {names[:8]}")
        assert archive.testzip() is None
        text = "".join(archive.read(n).decode("utf-8", "replace") for n in names
                       if n.endswith((".json", ".csv")))
    assert "A-18" in text and "reach the shelf" in text

    # erasing: a wrong name erases nothing, the right one erases
    page.once("dialog", lambda d: d.accept("someone else"))
    page.click("#erase-patient")
    sync_api.expect(page.locator("#record-card .error")).to_contain_text(
        "nothing was erased", timeout=SLOW_MS)
    assert api.http.get(f"/api/patients/{pid}").status_code == 200
    page.once("dialog", lambda d: d.accept(NAME))
    page.click("#erase-patient")
    page.wait_for_url(re.compile(r".*/patients$"), timeout=SLOW_MS)
    assert api.http.get(f"/api/patients/{pid}").status_code == 404
    assert api.http.get(f"/api/sessions/{interrupted_id}").status_code == 404
    sync_api.expect(page.locator("#patients tbody tr", has_text=NAME)).to_have_count(0)
