"""The live page follows the patient, in a real browser (Debian's headless chromium,
Playwright) against a real server fed by the kit emulator over a real WebSocket at real
pace: the current exercise is named in words and its repetitions are counted as they
happen; when the patient ends the session and starts the next, the page shows a banner
and moves to the new session by itself, with the day's sessions in a strip.

Every wait is on a condition with a generous timeout (the machine may be busy: the
count may lag, it must not stay at zero — ``tests/test_live_motion.py``). Screenshots go
to ``ARMTRACK_SCREENSHOTS`` (else a temporary folder, printed)."""

from __future__ import annotations

import itertools
import json
import re
import threading

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


#: Logs every answer of the page's live polls: when, the count, how far the count has
#: reached and the stream's time (to print how far the count lagged).
LOG_POLLS = """
window.__live = [];
const realFetch = window.fetch;
window.fetch = async (...args) => {
  const sent = performance.now() / 1000;
  const response = await realFetch(...args);
  const url = String(args[0] && args[0].url || args[0]);
  if (/\\/api\\/patients\\/\\d+\\/live$/.test(url)) {
    response.clone().json().then((s) => window.__live.push({
      sent, at: performance.now() / 1000, session: s.session && s.session.id,
      reps: s.exercise ? s.exercise.repetitions : null,
      counted_to: s.exercise ? s.exercise.counted_to_s : null,
      stream: s.calibration ? s.calibration.stream_time_s : null })).catch(() => {});
  }
  return response;
};
"""


def lag_summary(page) -> str:
    """The live answers' count and lag, in a line per change of the count."""
    log = page.evaluate("window.__live || []")
    lines, last = [], object()
    for a in log:
        if a["reps"] != last:
            last = a["reps"]
            lag = (a["stream"] - a["counted_to"] if a["stream"] is not None
                   and a["counted_to"] is not None else None)
            lines.append(f"  {a['at']:7.1f} s: session {a['session']}, {a['reps']} reps, "
                         f"stream {a['stream']}, count {'?' if lag is None else f'{lag:.1f} s'} "
                         "behind")
    waits = sorted(a["at"] - a["sent"] for a in log)
    gaps = sorted(b["sent"] - a["sent"] for a, b in itertools.pairwise(log))
    return (f"{len(log)} live answers; answer took median {waits[len(waits) // 2]:.2f} s, "
            f"longest {waits[-1]:.2f} s; between polls median {gaps[len(gaps) // 2]:.2f} s, "
            f"longest {gaps[-1]:.2f} s\n" + "\n".join(lines)) if gaps else "no live answers"


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
    page.add_init_script(LOG_POLLS)
    sign_in(page, module_server.url)
    page.wait_for_url(re.compile(r".*/patients$"))

    # the patient rests 15 s after the last repetition before the kit says bye; 10 s into
    # the rest (the exercise still marked) the kit waits until the page has counted them
    # all: a count lagging on a loaded machine is seen while the session is live
    recording = short_exercise("elbow_flexion", REPETITIONS, tail_s=15.0)
    last_t = min(float(s.t[-1]) for s in recording.sensors.values())
    all_counted = threading.Event()
    first_kit = KitThread(recording, module_server.ws_url, device["token"],
                          gates=[(last_t - 5.0, all_counted)])
    live = api.live_session(patient["id"])  # the stream's session
    page.goto(f"{module_server.url}/sessions/{live['id']}")

    # the exercise in words, and its count rising as the repetitions happen
    sync_api.expect(page.locator("#exercise-now .label")).to_have_text("Exercise now")
    sync_api.expect(page.locator("#exercise-name")).to_have_text("Elbow flexion",
                                                                 timeout=90_000)
    seen = []
    try:
        for target in range(1, REPETITIONS + 1):
            page.wait_for_function(
                "n => parseInt(document.getElementById('exercise-reps')?.textContent) >= n",
                arg=target, timeout=NEXT_COUNT_MS)
            seen.append(shown_count(page))
            if target == 2:
                page.screenshot(path=str(shots / "live-exercise-1366.png"), full_page=True,
                                timeout=90_000)
                no_horizontal_overflow(page, "live page at 1366")
    finally:
        all_counted.set()  # the kit rests on and says bye
        print(lag_summary(page))
    print(f"live repetitions as they showed: {seen}")
    assert seen == sorted(seen) and seen[-1] == REPETITIONS
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
        first_url = f"{module_server.url}/sessions/{live['id']}"
        page.wait_for_url(lambda url: "/sessions/" in url and url != first_url,
                          timeout=60_000)  # (survives the navigation it waits for)
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
        desktop_view = page.locator("#viewer-frame").get_attribute("src", timeout=30_000)
        page.set_viewport_size({"width": 390, "height": 844})
        sync_api.expect(page.locator("#exercise-name")).to_be_visible()
        # the 3D view keeps viser's desktop layout, scaled down (viewer_fit.js): its
        # phone layout would open the control panel over the scene. The page then asks
        # for a view with labels sized for the scale (a new grant, a new frame): read
        # that frame, not the one about to be replaced.
        scale = page.wait_for_function(
            "(old) => { const f = document.getElementById('viewer-frame');"
            " return f && f.getAttribute('src') !== old && f.style.width === '600px'"
            " && getComputedStyle(f).transform; }", arg=desktop_view,
            timeout=60_000).json_value()
        assert scale.startswith("matrix(0.") or scale.startswith("matrix(0,"), scale
        no_horizontal_overflow(page, "live page at 390")
        page.screenshot(path=str(shots / "live-followed-390.png"), full_page=True,
                        timeout=90_000)
    finally:
        second_kit.cut()

    # the first session's report counts what the page counted
    api.wait_processed(live["id"], 120)
    report = api.http.get(f"/api/sessions/{live['id']}/report")
    assert report.status_code == 200, report.text
    total = max(a["repetitions"] for a in report.json()["exercises"][0]["angles"])
    print(f"report: {total} repetitions; live page: {seen[-1]}")
    assert total == REPETITIONS == seen[-1]


def test_a_both_ways_repetition_under_way_reads_whole_at_390_and_1280_px(
        module_server, page, shots):
    """A both-ways repetition with its first turn made (``repetitions`` 1,
    ``repetitions_done`` 0, as test_one_repetition_count measures it on a real stream):
    the page says "0 repetitions" and, apart, "one under way", on one line of its own at
    390 px (before: one run of large text that broke "one under / way"). The live status
    is the server's, its exercise set to that state (a real stream reaches it only after
    ~17 s of live estimation)."""
    from armtrack.estimator.simulation import SimulationConfig, simulate
    from armtrack.server.emulator import MessagePlan, hello_message
    from browser_helpers import sign_in_as
    from websockets.sync.client import connect

    api = module_server.client("alice")
    recording = simulate(SimulationConfig(exercise="pronation", repetitions=1, seed=5)).recording
    patient = api.patient("Palm Turner")
    token = api.device(patient["id"], "kit")["token"]

    def first_turn_made(route):
        answer = route.fetch()
        status = answer.json()
        status["exercise"] = {
            "name": "pronation", "label": "Turn the palm (pronation/supination)",
            "source": "marks", "since_s": 0.0, "angle": "forearm_rotation",
            "counted_to_s": (status.get("calibration") or {}).get("stream_time_s"),
            "repetitions": 1, "repetitions_done": 0}
        route.fulfill(response=answer, body=json.dumps(status))

    with connect(f"{module_server.ws_url}?token={token}") as ws:
        ws.send(json.dumps(hello_message(recording, "kit")))
        session = json.loads(ws.recv(timeout=30))["session"]
        ws.send(MessagePlan(recording).encode(0))
        sign_in_as(page, module_server.url, "alice")
        page.route(f"**/api/patients/{patient['id']}/live", first_turn_made)
        page.set_viewport_size({"width": 390, "height": 844})
        page.goto(f"{module_server.url}/sessions/{session}")
        for width in (390, 1280):
            page.set_viewport_size({"width": width, "height": 900})
            under_way = page.locator("#exercise-reps .under-way")
            sync_api.expect(under_way).to_have_text("one under way", timeout=30_000)
            box = page.locator("#exercise-now")
            box.screenshot(path=str(shots / f"live-under-way-{width}.png"))
            print(f"at {width}: {box.inner_text()!r}")
            assert page.locator("#exercise-reps").inner_text().startswith("0 repetitions")
            lines = page.evaluate(  # at once: each poll renders the count anew
                "document.querySelector('#exercise-reps .under-way').getClientRects().length")
            assert lines == 1, f"'one under way' broken over {lines} lines at {width} px"
            no_horizontal_overflow(page, f"live page at {width}")
