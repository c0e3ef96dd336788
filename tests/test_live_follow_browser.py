"""The live page follows the patient, in a real browser (Debian's headless chromium,
Playwright) against a real server fed by the kit emulator over a real WebSocket at real
pace: the current exercise is named in words and its repetitions are counted as they
happen; when the patient ends the session and starts the next, the page shows a banner
and moves to the new session by itself, with the day's sessions in a strip.

Every wait is on a condition with a generous timeout (the machine may be busy: the
count may lag, it must not stay at zero — ``tests/test_live_motion.py``). Screenshots go
to ``ARMTRACK_SCREENSHOTS`` (else a temporary folder, printed)."""

from __future__ import annotations

import re
import time

import pytest
import test_pages_browser
from test_live_motion import short_exercise
from test_pages_browser import KitThread, sign_in, sync_api

# the browser fixtures of test_pages_browser (one chromium per module)
browser_context = test_pages_browser.browser_context
page = test_pages_browser.page
shots = test_pages_browser.shots

pytestmark = pytest.mark.slow

#: Repetitions of the first session's exercise.
REPETITIONS = 6
#: How long one more repetition may take to show on the page [ms]: a repetition takes
#: ~4.5 s; a busy machine may delay the count by several more.
NEXT_COUNT_MS = 60_000


def no_horizontal_overflow(page, where: str) -> None:
    width = page.evaluate("document.documentElement.scrollWidth")
    inner = page.evaluate("window.innerWidth")
    print(f"{where}: page {width} px wide in a {inner} px window")
    assert width <= inner, f"{where}: the page is {width} px wide in a {inner} px window"


def shown_count(page) -> int | None:
    """The repetitions the page shows now (None: no count shown)."""
    text = page.evaluate("document.getElementById('exercise-reps')?.textContent ?? null")
    match = re.fullmatch(r"(\d+) repetitions?", text or "")
    return int(match.group(1)) if match else None


def test_the_live_page_names_counts_and_follows_the_patient(module_server, page, shots):
    api = module_server.client("alice")
    patient = api.patient("Follow Me")
    device = api.device(patient["id"])
    page.set_viewport_size({"width": 1366, "height": 900})
    sign_in(page, module_server.url)
    page.wait_for_url(re.compile(r".*/patients$"))

    first_kit = KitThread(short_exercise("elbow_flexion", REPETITIONS),
                          module_server.ws_url, device["token"])
    live = None
    deadline = time.monotonic() + 60
    while live is None and time.monotonic() < deadline:  # the stream's session
        live = api.http.get(f"/api/patients/{patient['id']}/live").json()["session"]
        if live is None:
            time.sleep(0.2)
    assert live, "the kit's stream did not start"
    page.goto(f"{module_server.url}/sessions/{live['id']}")

    # the exercise in words, and its count rising as the repetitions happen
    sync_api.expect(page.locator("#exercise-now .label")).to_have_text("Exercise now")
    sync_api.expect(page.locator("#exercise-name")).to_have_text("Elbow flexion",
                                                                 timeout=90_000)
    seen = []
    for target in range(1, REPETITIONS):
        page.wait_for_function(
            "n => parseInt(document.getElementById('exercise-reps')?.textContent) >= n",
            arg=target, timeout=NEXT_COUNT_MS)
        seen.append(shown_count(page))
        if target == 2:
            page.screenshot(path=str(shots / "live-exercise-1366.png"), full_page=True,
                            timeout=90_000)
            no_horizontal_overflow(page, "live page at 1366")
    print(f"live repetitions as they showed: {seen}")
    assert seen == sorted(seen) and seen[-1] >= REPETITIONS - 1
    assert "exercise:" not in page.inner_text("main")  # marks in words only
    first_kit.thread.join(120)
    assert not first_kit.thread.is_alive(), "the first kit did not finish"

    # the session ended: the page says so and keeps the day's sessions
    sync_api.expect(page.locator("#exercise-now")).to_have_count(0, timeout=60_000)
    sync_api.expect(page.locator("#day-history .day-session")).to_have_count(1,
                                                                             timeout=30_000)

    # the patient starts the next exercise: a banner, then the page moves there by itself
    second_kit = KitThread(short_exercise("shoulder_flexion", 10, seed=1),
                           module_server.ws_url, device["token"])
    try:
        banner = page.locator("#next-session")
        sync_api.expect(banner).to_be_visible(timeout=60_000)
        sync_api.expect(banner).to_contain_text("The patient started a new session")
        page.screenshot(path=str(shots / "live-banner-1366.png"), full_page=True,
                        timeout=90_000)
        page.wait_for_function(f"location.pathname !== '/sessions/{live['id']}'",
                               timeout=60_000)
        new_id = int(page.url.rsplit("/", 1)[1])
        assert new_id > live["id"]
        strip = page.locator("#day-history .day-session")
        sync_api.expect(strip).to_have_count(2, timeout=30_000)
        sync_api.expect(page.locator("#day-history .current")).to_have_attribute(
            "data-session", str(new_id))
        sync_api.expect(page.locator(f'#day-history a[data-session="{live["id"]}"]')
                        ).to_contain_text("Elbow flexion")
        sync_api.expect(page.locator("#exercise-name")).to_have_text("Shoulder flexion",
                                                                     timeout=90_000)
        page.screenshot(path=str(shots / "live-followed-1366.png"), full_page=True,
                        timeout=90_000)
        page.set_viewport_size({"width": 390, "height": 844})
        sync_api.expect(page.locator("#exercise-name")).to_be_visible()
        no_horizontal_overflow(page, "live page at 390")
        page.screenshot(path=str(shots / "live-followed-390.png"), full_page=True,
                        timeout=90_000)
    finally:
        second_kit.cut()

    # the first session's report counts what the page counted (the page may miss the
    # last one, completed as the kit said bye)
    api.wait_processed(live["id"], 120)
    report = api.http.get(f"/api/sessions/{live['id']}/report")
    assert report.status_code == 200, report.text
    total = max(a["repetitions"] for a in report.json()["exercises"][0]["angles"])
    print(f"report: {total} repetitions; live page: {seen[-1]}")
    assert total == REPETITIONS
    assert total - 1 <= seen[-1] <= total
