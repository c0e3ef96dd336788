"""The patient page's upload dialog in real headless chromium (390 and 1366 px): choose
vendor files, see which sensor each is with its rate and duration and the suggested
segment, a side/height mismatch said before processing, import, follow the progress to
"done", and find the new session in the list. Screenshots go to a folder (printed;
``ARMTRACK_SCREENSHOTS`` chooses it). Skips when chromium or Playwright is absent."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from functools import cache

import pytest
from armtrack.estimator.recording import format_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from importer_layouts import xsens_dot_csv
from test_pages_browser import browser_context, page, shots, sign_in, sync_api  # noqa: F401

pytestmark = pytest.mark.slow
SENSORS = ("upper_arm", "forearm", "hand")


@cache
def sim():
    return simulate(SimulationConfig(rate_hz=60.0, repetitions=2, seed=11))


def dot_payloads():
    rec = sim().recording
    names = {"upper_arm": "Right Upper Arm_D422CD0011A2.csv", "forearm": "forearm_D422CD0011B7.csv",
             "hand": "hand_D422CD0011C3.csv"}
    return [{"name": names[s], "mimeType": "text/csv",
             "buffer": xsens_dot_csv(rec.sensors[s], f"DOT {s.replace('_', ' ')}")}
            for s in SENSORS]


@pytest.mark.parametrize("width,height", [(1366, 900), (390, 844)])
def test_upload_dialog_imports_vendor_files(module_server, page, shots, width, height):  # noqa: F811
    api = module_server.client("alice")
    patient = api.patient(f"Ida {width}", side="right", height_m=1.75)
    page.set_viewport_size({"width": width, "height": height})
    sign_in(page, module_server.url)
    page.goto(f"{module_server.url}/patients/{patient['id']}")
    sync_api.expect(page.locator("h1")).to_have_text(f"Ida {width}")
    page.click("#import-open")
    sync_api.expect(page.locator("#import-dialog")).to_be_visible()

    # an armtrack recording of the other arm and another height: said before processing
    left = replace(sim().recording, side="left", height_m=1.62)
    page.set_input_files("#import-files", files=[{"name": "left-arm.csv", "mimeType": "text/csv",
                                                  "buffer": format_recording(left)}])
    warnings = page.locator("#import-warnings")
    sync_api.expect(warnings).to_contain_text("the file records the left arm; right is the "
                                              "patient's treated arm on record")
    sync_api.expect(warnings).to_contain_text("body height is 1.62 m")
    page.screenshot(path=str(shots / f"import-mismatch-{width}.png"), full_page=True)

    page.set_input_files("#import-files", files=dot_payloads())
    rows = page.locator("#import-found tbody tr")
    sync_api.expect(rows).to_have_count(3)
    for i, sensor in enumerate(SENSORS):
        row = rows.nth(i)
        sync_api.expect(row).to_contain_text("60 Hz")
        assert row.locator("select").input_value() == sensor
    shown = rows.nth(2).locator("td").nth(4).inner_text()  # duration, e.g. "21.3 s"
    hand_s = float(sim().recording.sensors["hand"].t[-1])
    assert abs(float(shown.removesuffix(" s")) - hand_s) < 0.06
    calibration = page.locator("#import-calibration")
    sync_api.expect(calibration).to_have_value(re.compile(r"npose \d+\.\d \d+\.\d; tpose "))
    sync_api.expect(page.locator("#import-warnings")).to_have_count(0)
    page.screenshot(path=str(shots / f"import-files-{width}.png"), full_page=True)

    # two sensors on one segment: refused in the dialog
    rows.nth(2).locator("select").select_option("forearm")
    sync_api.expect(page.locator("#import-status")).to_contain_text("Two sensors are assigned")
    assert page.locator("#import-go").is_disabled()
    rows.nth(2).locator("select").select_option("hand")

    page.click("#import-go")
    sync_api.expect(page.locator("#import-done")).to_be_visible(timeout=120_000)
    page.screenshot(path=str(shots / f"import-done-{width}.png"), full_page=True)
    href = page.locator("#import-done a").get_attribute("href")
    session_id = int(href.rsplit("/", 1)[1])
    session = api.session(session_id)
    print(json.dumps({k: session[k] for k in ("sensors", "samples", "processed", "metadata")}))
    assert session["sensors"] == list(SENSORS) and session["processed"]
    assert session["metadata"]["import_format"] == "xsens-dot"
    page.click("#import-close")
    sync_api.expect(page.locator(f'#sessions tr[data-session="{session_id}"]')).to_be_visible()
    page.screenshot(path=str(shots / f"import-sessions-{width}.png"), full_page=True)
