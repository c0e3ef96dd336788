"""A phone session cut short long ago (the battery died, the page was closed) is not
carried on when the patient opens the page again hours later: that session is sent as it
is and ended, and the page starts the day afresh from its welcome, with the two arm poses.

Before, the page resumed it wherever it stood, whatever the time since: the next day's
exercises went into the day before's session (a session of 20 hours, one set marked from
yesterday to today, counted on yesterday's date), measured against calibration poses held
before the phone was taken off the arm to be charged, and the old session stayed
"interrupted" on the therapist's page until then. A reopen within minutes (a reload, a tab
closed by mistake) still carries on the same session (test_phone_kit_browser).

Debian's headless chromium at 390 px against a real server; the phone's browser is closed
and opened again on the same profile (its storage kept), and "hours later" is the kept
session's start moved back on the phone (its clock, not the test's, says how long ago)."""

from __future__ import annotations

import shutil
import tempfile

import pytest
import test_phone_kit_server_restart_browser as restart_test
from browser_helpers import ARGS, CHROMIUM, first_page, need_browser, screenshots_folder
from test_phone_kit_browser import FEEDER, _wait, motion_events, phone_simulation

sync_api = need_browser()

server = restart_test.server  # a real server per test (killed and started again offline)

pytestmark = pytest.mark.slow

#: Moves the kept session's start back by ``shift`` seconds (as if it had been recorded
#: that long ago), run on a page of the kit's origin that is not the kit. With ``asleep``,
#: only its session clock (startEpoch + t) moves, not the wall-clock time of its last
#: reading: what a phone's sleep does (``performance.now()`` does not tick while a phone
#: sleeps, MDN "Ticking during sleep": only Windows' browsers do), so that a session locked
#: between sets falls behind the wall clock by every sleep while its readings are recent.
AGE_THE_KEPT_SESSION = """async ([shift, asleep]) => {
  const db = await new Promise((ok, no) => {
    const r = indexedDB.open("armtrack-kit", 1);
    r.onsuccess = () => ok(r.result);
    r.onerror = no;
  });
  const tx = db.transaction(["state"], "readwrite");
  const store = tx.objectStore("state");
  const state = await new Promise((ok) => {
    const r = store.get("stream");
    r.onsuccess = () => ok(r.result);
  });
  state.startEpoch -= shift;
  if (state.lastWall && !asleep) state.lastWall -= shift;
  store.put(state, "stream");
  await new Promise((ok) => { tx.oncomplete = ok; });
  return state.session;
}"""


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    return screenshots_folder(tmp_path_factory, "stale-shots")


@pytest.fixture
def phone_profile():
    """A phone browser's profile folder, kept across its closing and opening again."""
    folder = tempfile.mkdtemp(prefix="armtrack-phone-")
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def open_phone(playwright, profile: str):
    return playwright.chromium.launch_persistent_context(
        profile, executable_path=CHROMIUM, args=ARGS, headless=True,
        viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True)


def cut_short(playwright, server, profile: str, events) -> tuple[int, int]:
    """A phone session of 10 s (the arm-down pose and on), then the battery dies: the
    browser is closed. Its session and the readings taken."""
    api = server.client("alice")
    patient = api.patient("Charged Overnight")
    token = api.device(patient["id"], "phone")["token"]
    context = open_phone(playwright, profile)
    phone = first_page(context)
    phone.goto(f"{server.url}/kit#token={token}")
    phone.click("#start")
    phone.click("#segment-forearm")
    phone.click("#ready")
    phone.evaluate(FEEDER, events[:600])
    _wait(lambda: phone.evaluate("window.__feed.i >= 600"), 60, "10 s of readings")
    # closing the browser runs no pagehide (no keepTail): the readings of the last 0.1 s
    # (kit.stream.rows) and messages whose save is under way (_unsaved) would be lost with
    # it, and the old session then holds fewer than ``taken`` (a fixed 0.5 s let them reach
    # IndexedDB on an idle machine only)
    _wait(lambda: phone.evaluate("kit.stream.state.session != null "
                                 "&& kit.stream.rows.length === 0 "
                                 "&& kit.stream._unsaved.size === 0"), 30,
          "every reading taken saved on the phone")
    taken = phone.evaluate("kit.stream.samples")
    session = phone.evaluate("kit.stream.state.session")
    context.close()
    return session, taken


def aged(playwright, server, profile: str, session: int, hours: float):
    """The phone opened again, its kept session moved ``hours`` back (still on the kit's
    origin, not on the kit page)."""
    context = open_phone(playwright, profile)
    phone = first_page(context)
    phone.goto(f"{server.url}/healthz")
    assert phone.evaluate(AGE_THE_KEPT_SESSION, [hours * 3600, False]) == session
    return context, phone


def test_a_session_cut_short_hours_ago_is_ended_and_the_day_starts_afresh(
        server, phone_profile, shots):
    api = server.client("alice")
    events = motion_events(phone_simulation(seed=7))
    with sync_api.sync_playwright() as playwright:
        old, taken = cut_short(playwright, server, phone_profile, events)
        context, phone = aged(playwright, server, phone_profile, old, 20)
        phone.goto(f"{server.url}/kit")
        # the next day: not yesterday's session carried on at its arm-down pose, but
        # today's welcome once yesterday's is sent
        sync_api.expect(phone.locator("#start")).to_be_visible(timeout=60_000)
        said = phone.locator("body").inner_text()
        phone.screenshot(path=str(shots / "next-day-welcome.png"))
        print(f"\nopened 20 h after the battery died, the phone says: {said!r}")
        assert "stopped part way" in said
        # the welcome follows the bye once it is sent (sendAndEnd: state.finished); the
        # server closes the session when it handles the bye, a moment later on a busy
        # machine: "live" read in between is not a session left open
        _wait(lambda: api.session(old)["status"] != "live", 30, "the old session's bye handled")
        session = api.session(old)
        print(f"the old session: {session['status']}, {session['samples']} of the "
              f"{taken} readings taken before the battery died")
        assert session["status"] == "closed" and session["samples"] == taken

        # today's session is a new one, calibrated afresh
        phone.click("#start")
        phone.click("#segment-forearm")
        phone.click("#ready")
        phone.evaluate(FEEDER, events[:120])
        sync_api.expect(phone.locator("h1")).to_contain_text("Arm down")
        _wait(lambda: phone.evaluate("kit.stream.state && kit.stream.state.session"), 30,
              "today's session opened")
        assert phone.evaluate("kit.stream.state.session") != old
        context.close()


def test_offline_the_patient_may_carry_on_the_old_session(server, phone_profile, shots):
    """Offline the old session cannot be sent, and a new one waits for it: the page says
    it is saved and offers to carry on with it instead (as before), which loses nothing."""
    api = server.client("alice")
    events = motion_events(phone_simulation(seed=8))
    with sync_api.sync_playwright() as playwright:
        old, taken = cut_short(playwright, server, phone_profile, events)
        context, phone = aged(playwright, server, phone_profile, old, 20)
        server.kill()  # no network: the page opens from the phone's cache
        phone.goto(f"{server.url}/kit")
        sync_api.expect(phone.locator("#carry-on")).to_be_visible(timeout=30_000)
        said = phone.locator("body").inner_text()
        phone.screenshot(path=str(shots / "next-day-offline.png"))
        print(f"\nopened offline 20 h later, the phone says: {said!r}")
        assert "will send when online" in said
        phone.click("#carry-on")
        sync_api.expect(phone.locator("#start")).to_be_hidden()
        _wait(lambda: phone.evaluate("Boolean(kit.stream && kit.stream.state)"), 30,
              "the old session resumed")
        assert phone.evaluate("kit.stream.state.session") == old
        server.start(timeout=180)
        _wait(lambda: phone.evaluate("kit.stream.connected && kit.stream.unsent === 0"), 90,
              "sent once online")
        assert not phone.evaluate("kit.stream.ended")  # carried on, not ended meanwhile
        assert api.session(old)["samples"] >= taken
        assert api.session(old)["status"] == "live"
        context.close()


def test_a_session_whose_clock_fell_behind_in_sleep_is_carried_on(server, phone_profile):
    """A phone locked between sets sleeps, and its page's clock (``performance.now()``)
    stops meanwhile: 40 minutes locked put the session clock 40 minutes behind. Closed by
    mistake and opened again a minute after its last reading, the session is carried on,
    not ended as if cut short 40 minutes ago: how long ago is read on the wall clock."""
    events = motion_events(phone_simulation(seed=9))
    with sync_api.sync_playwright() as playwright:
        old, _ = cut_short(playwright, server, phone_profile, events)
        context = open_phone(playwright, phone_profile)
        phone = first_page(context)
        phone.goto(f"{server.url}/healthz")
        assert phone.evaluate(AGE_THE_KEPT_SESSION, [40 * 60, True]) == old
        phone.goto(f"{server.url}/kit")
        sync_api.expect(phone.locator("h1")).to_contain_text("Continue your session",
                                                             timeout=60_000)
        print(f"\nits clock 40 min behind, reopened at once: {phone.locator('h1').inner_text()!r}")
        context.close()
