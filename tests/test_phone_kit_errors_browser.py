"""What the patient's phone kit says when it cannot go on, at 390 px on a real server:
the phone refused the page its motion sensors (iOS asks once: a "Don't allow" is kept),
and a link cut short in the message that carried it. Each screen says what happened in
the patient's words and what to do; no session is made. Screenshots go to a folder
(printed; ``ARMTRACK_SCREENSHOTS``)."""

from __future__ import annotations

import pytest
from browser_helpers import ARGS, chromium, first_page, need_browser, screenshots_folder
from server_support import server_fixture

sync_api = need_browser()

server = server_fixture("kit-errors-server", "alice")

#: iOS Safari's answer after the patient tapped "Don't allow" (kept for the site: the
#: phone does not ask again at the next tap).
REFUSING_PHONE = """
window.DeviceMotionEvent
  && (DeviceMotionEvent.requestPermission = async () => "denied");
"""


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    return screenshots_folder(tmp_path_factory, "kit-error-shots")


@pytest.fixture
def phone():
    """A phone-sized chromium (390 × 844, touch) with its own profile."""
    with (sync_api.sync_playwright() as playwright,
          chromium(playwright, 390, 844, phone=True, device_scale_factor=1,
                   args=ARGS) as context):
        yield first_page(context)


def fits(page) -> None:
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, f"the screen is {width} px wide at 390"


def test_motion_sensors_refused_says_how_to_allow_them(server, phone, shots):
    """Found: the screen said "motion sensors were not allowed" (the code's words, lower
    case) and "Open this page in Chrome or Safari, from the https link, and allow motion
    sensors when asked" to a patient who was there already, and whose phone does not ask
    again."""
    api = server.client("alice")
    patient = api.patient("Refusing Phone")
    device = api.device(patient["id"], "phone")
    phone.add_init_script(REFUSING_PHONE)
    phone.goto(f"{server.url}/kit#token={device['token']}")
    phone.click("#start")
    phone.click("#segment-forearm")
    sync_api.expect(phone.locator("h1")).to_have_text("The phone's motion sensors")
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "refused-motion.png"))
    assert "motion sensors were not allowed" not in said
    assert "did not let this page use its motion sensors" in said
    assert "Allow" in said  # what to tap when the phone asks again
    assert "close the browser" in said  # what to do when it does not
    fits(phone)
    sync_api.expect(phone.get_by_role("button", name="Try again")).to_be_visible()
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


def test_a_link_cut_short_says_so_and_keeps_the_phones_kit(server, phone, shots):
    """Found: a link cut short (a message app broke it, the patient copied part of it)
    said "This link no longer works. Your therapist has replaced or removed it." — not
    so — and took the place of the phone's working link, so the home-screen kit stopped
    working too. Now it says the link is incomplete and what to do; the phone keeps its
    kit; a revoked link still says it no longer works."""
    api = server.client("alice")
    patient = api.patient("Cut Link")
    token = api.device(patient["id"], "phone")["token"]
    phone.goto(f"{server.url}/kit#token={token}")
    sync_api.expect(phone.locator("#start")).to_be_visible()

    phone.goto(f"{server.url}/kit#token={token[:30]}")
    sync_api.expect(phone.locator("h1")).to_have_text("This link is incomplete")
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "cut-link.png"))
    assert "replaced or removed" not in said
    assert "whole link" in said and "QR code" in said
    fits(phone)

    phone.goto(f"{server.url}/kit")  # the home-screen icon: the phone's kit still works
    sync_api.expect(phone.locator("#start")).to_be_visible()

    revoked = api.device(patient["id"], "old phone")
    assert api.http.delete(f"/api/devices/{revoked['id']}").status_code == 204
    phone.goto(f"{server.url}/kit#token={revoked['token']}")
    sync_api.expect(phone.locator("h1")).to_have_text("This link no longer works")


def test_the_program_says_changed_by_your_therapist_not_a_version_number(server, phone, shots):
    """Found (three new-user passes): under the program's name the patient read "Version 1"
    — a number that says nothing to them. A first program says nothing of versions; a
    changed one says the therapist changed it."""
    from datetime import UTC, datetime

    api = server.client("alice")
    patient = api.patient("Program Words")
    device = api.device(patient["id"], "phone")
    today = datetime.now(UTC).date().isoformat()  # the server's clinic zone is UTC
    body = {"name": "Elbow after the fracture", "start_date": today, "exercises": [
        {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5}]}
    made = api.http.post(f"/api/patients/{patient['id']}/programs", json=body)
    assert made.status_code == 201, made.text
    phone.goto(f"{server.url}/kit#token={device['token']}")
    sync_api.expect(phone.locator("#program-name")).to_have_text("Elbow after the fracture")
    first = phone.locator("#screen").inner_text()
    print("\n" + first)
    assert "Version" not in first and phone.locator("#program-version").count() == 0

    changed = api.http.put(f"/api/programs/{made.json()['id']}",
                           json={k: v for k, v in body.items() if k != "name"})
    assert changed.status_code == 200, changed.text
    phone.reload()
    sync_api.expect(phone.locator("#program-version")).to_have_text(
        "Changed by your therapist today")
    phone.screenshot(path=str(shots / "program-changed.png"))
    assert "Version" not in phone.locator("#screen").inner_text()


def test_another_patients_link_does_not_show_the_last_patients_session(server, phone, shots):
    """The welcome's "Last time" list (c7c5b31) is kept on the phone, not with its kit: a
    phone opened with another patient's link (a clinic's phone lent in turn, a family's
    shared one) showed the last patient's exercises, repetitions and ranges to the next.
    A link of another kit now starts with none; the same kit's keeps it."""
    api = server.client("alice")
    first = api.device(api.patient("Lent First")["id"], "clinic phone")["token"]
    second = api.device(api.patient("Lent Second")["id"], "clinic phone")["token"]
    phone.goto(f"{server.url}/kit#token={first}")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    # what the finished screen keeps (kit.js finished(): LAST_KEY)
    phone.evaluate("""localStorage.setItem("armtrack.kit.last", JSON.stringify({at: Date.now(),
        lines: ["Bend the elbow: 7 of 10 repetitions · from 0° to 120° (target 0° to 120°)"]}))""")
    phone.goto(f"{server.url}/kit#token={first}")  # the same kit's link again
    sync_api.expect(phone.locator("#last-session")).to_contain_text("7 of 10 repetitions")

    phone.goto(f"{server.url}/kit#token={second}")
    phone.click("#replace-kit")  # asked first (test_phone_kit_link_switch_browser)
    sync_api.expect(phone.locator("#start")).to_be_visible()
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "lent-phone.png"))
    assert "7 of 10" not in said and phone.locator("#last-session").count() == 0


def test_a_phone_strapped_upside_down_is_told_at_the_arm_down_pose(server, phone, shots):
    """Found by a new user: the strap screen said "Turn the phone round", but "I'm ready"
    goes on all the same, and the arm-down pose then said "Get into position…" for good
    to a patient standing still with the arm hanging (the pose wants the phone's top up):
    no word of what was wrong. Now the pose says to turn the phone round."""
    from test_phone_kit_browser import FEEDER, motion_events, phone_simulation

    api = server.client("alice")
    device = api.device(api.patient("Upside Down")["id"], "phone")
    # the simulated forearm's first 2 s (arm hanging, still), the phone turned 180° about
    # its screen's normal: x and y (and their rates) change sign
    events = [[t, -x, -y, z, alpha, -beta, -gamma]
              for t, x, y, z, alpha, beta, gamma in motion_events(phone_simulation())[:120]]
    phone.goto(f"{server.url}/kit#token={device['token']}")
    phone.click("#start")
    phone.click("#segment-forearm")
    phone.click("#ready")
    phone.evaluate(FEEDER, events)
    sync_api.expect(phone.locator("h1")).to_have_text("Arm down, hold still")
    sync_api.expect(phone.locator("#hold")).to_contain_text("Turn the phone round",
                                                            timeout=10_000)
    said = phone.locator("#screen").inner_text()
    print("\n" + said)
    phone.screenshot(path=str(shots / "upside-down-npose.png"))
    assert "top toward your elbow" in said
    fits(phone)


def test_a_band_nobody_set_is_called_the_usual_range_not_a_target(server, phone, shots):
    """The therapist set no target: the phone showed the exercise's usual range as
    "target 0° to 120°", while the therapist's report says "Target then: –" (no target
    was set). Now the phone calls it what it is, "usual range 0° to 120°", on the
    exercise screen and in what was done (one ``KitProgram.bandWords``); a band the
    therapist set (the program's, the patient's target) is still "target"."""
    api = server.client("alice")
    token = api.device(api.patient("Usual Range")["id"], "phone")["token"]
    phone.goto(f"{server.url}/kit#token={token}")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    words = phone.evaluate("""() => ["default", "catalogue", "patient", "program"].map((from) =>
        KitProgram.didLine("Bend the elbow", 7, 10, 2, 101, {min_deg: 0, max_deg: 120, from}))""")
    print("\n" + "\n".join(words))
    assert [w.endswith("(usual range 0° to 120°)") for w in words] == [True, True, False, False]
    assert [w.endswith("(target 0° to 120°)") for w in words] == [False, False, True, True]
    phone.evaluate("""(lines) => localStorage.setItem("armtrack.kit.last",
        JSON.stringify({at: Date.now(), lines}))""", words[:1] + words[3:])
    phone.goto(f"{server.url}/kit#token={token}")
    sync_api.expect(phone.locator("#last-session")).to_contain_text("usual range 0° to 120°")
    fits(phone)
    phone.screenshot(path=str(shots / "usual-range-390.png"), full_page=True)
    phone.set_viewport_size({"width": 1280, "height": 900})
    phone.screenshot(path=str(shots / "usual-range-1280.png"), full_page=True)


def test_turning_the_palm_says_palm_up_or_down_not_a_signed_angle(server, phone, shots):
    """Found by a new user: Turn the palm showed "usual range -70° to 70°" and the live
    number read −45° for the palm turned up; a patient does not read signed angles. Now
    the phone says the side in words, in kinematics.md's signs (pronation +: palm down;
    supination −: palm up), on the exercise screen (band and live number) and in what
    was done; the API's numbers stay signed. The live screen is the page's own
    ``exercise`` with a feedback message set as the stream would (no 60-s feed)."""
    api = server.client("alice")
    token = api.device(api.patient("Palm Words")["id"], "phone")["token"]
    phone.goto(f"{server.url}/kit#token={token}")
    sync_api.expect(phone.locator("#start")).to_be_visible()
    today = api.http.get("/api/device/today", headers={"Authorization": f"Bearer {token}"}).json()
    palm = next(e for e in today["exercises"] if e["name"] == "pronation")
    assert (palm["angle"], palm["target"]["min_deg"], palm["target"]["max_deg"]) == (
        "forearm_pronation", -70.0, 70.0)  # the contract keeps its signs
    index = phone.evaluate("""() => {
        kit.sensor = "forearm";
        kit.stream = { now: () => 0, mark() {}, connected: true };  // no session needed here
        const i = exercisesForKit().findIndex((e) => e.name === "pronation");
        exercise(i);
        return i;
    }""")
    assert index >= 0
    sync_api.expect(phone.locator(".live .target")).to_have_text(
        "usual range 70° palm up to 70° palm down")
    for deg, said in ((-45.4, "45° palm up"), (30, "30° palm down"), (0.2, "0°")):
        phone.evaluate("""(deg) => { kit.feedback = { exercise: "pronation", t: 1, angle_deg: deg,
            repetitions: 0, count_from: 0 }; kit.feedbackAt = Date.now(); }""", deg)
        # the side is on a line of its own, under the number
        sync_api.expect(phone.locator("#angle")).to_have_text(said, use_inner_text=True)
        if deg == -45.4:
            fits(phone)
            phone.screenshot(path=str(shots / "palm-up-390.png"))
    words = phone.evaluate("""() => [
        KitProgram.didLine("Turn the palm", 8, 10, -52, 61,
                           {min_deg: -70, max_deg: 70, from: "default"}, "forearm_pronation"),
        KitProgram.didLine("Bend the elbow", 7, 10, 2, 101,
                           {min_deg: 0, max_deg: 120, from: "program"}, "elbow_flexion")]""")
    print("\n" + "\n".join(words))
    assert words == [
        "Turn the palm: 8 of 10 repetitions · from 52° palm up to 61° palm down"
        " (usual range 70° palm up to 70° palm down)",
        "Bend the elbow: 7 of 10 repetitions · from 2° to 101° (target 0° to 120°)"]
