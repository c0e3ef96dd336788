"""The phone kit's pictures show the patient's own arm: a patient whose therapist set the
left arm sees the figure with the phone on its left arm, the mirror image of the right
arm's (before, every picture showed the right arm). In Debian's headless chromium at 390
px against a real server: the segment choice and the strap screen, for a right-arm and a
left-arm patient; the side of each picture's phone and arm is read from the page (where
they are drawn on the screen, against the head's centre), and screenshots are saved."""

from __future__ import annotations

import pytest
import test_phone_kit_browser as kit_browser
from test_phone_kit_browser import sync_api

# a 390 px phone and the screenshots' folder of the phone kit's tests
phone = kit_browser.phone
shots = kit_browser.shots

pytestmark = pytest.mark.slow

#: Per picture on the screen: the screen x [px] of the head's centre, of the phone's
#: centre and of the moving arm's segments' centres (the arm drawn in ARM blue).
WHERE = """() => [...document.querySelectorAll('.picture svg')].map((svg) => {
  const mid = (r) => r.left + r.width / 2;
  const head = svg.querySelector('circle[fill="none"]').getBoundingClientRect();
  const arm = [...svg.querySelectorAll('line')]
    .filter((l) => l.getAttribute('stroke') === '#1f6fb2')
    .map((l) => mid(l.getBoundingClientRect()));
  const phone = svg.querySelector('rect');
  return { label: svg.getAttribute('aria-label'), head: mid(head), arm,
           phone: phone ? mid(phone.getBoundingClientRect()) : null };
})"""


def _pictures(page) -> list[dict]:
    """Each picture's phone and arm as offsets from its head's centre [px, + to the right
    on the screen]."""
    return [{"label": p["label"], "phone": None if p["phone"] is None else p["phone"] - p["head"],
             "arm": [round(a - p["head"], 1) for a in p["arm"]]}
            for p in page.evaluate(WHERE)]


def test_the_pictures_show_the_arm_the_therapist_set(module_server, phone, shots):
    api = module_server.client("alice")
    seen = {}
    for side in ("right", "left"):
        patient = api.patient(f"Pictures {side}", side=side)
        token = api.device(patient["id"], "phone")["token"]
        phone.goto(f"{module_server.url}/kit#token={token}")
        phone.click("#start")
        sync_api.expect(phone.locator("#segment-forearm")).to_be_visible()
        phone.screenshot(path=str(shots / f"pictures-{side}-segment.png"))
        choice = _pictures(phone)
        phone.click("#segment-forearm")
        sync_api.expect(phone.locator("#ready")).to_be_visible()
        sync_api.expect(phone.locator("#screen")).to_contain_text(
            f"outside of your {side} forearm")
        phone.screenshot(path=str(shots / f"pictures-{side}-strap.png"))
        seen[side] = choice + _pictures(phone)
        phone.evaluate("localStorage.clear()")  # the next patient's link, afresh
        print(f"\n{side} arm: " + "; ".join(
            f"{p['label']}: phone {p['phone']:+.1f} px, arm {p['arm']} px from the head"
            for p in seen[side]))

    assert len(seen["right"]) == len(seen["left"]) == 3  # two choices, the strap's
    for right, left in zip(seen["right"], seen["left"], strict=True):
        assert right["label"] == left["label"]
        # the right arm to the right of the head on the screen (as the pictures were
        # drawn), the left arm to the left: the same figure, mirrored
        assert right["phone"] > 5 and all(a > 5 for a in right["arm"]), right
        assert left["phone"] < -5 and all(a < -5 for a in left["arm"]), left
        assert abs(right["phone"] + left["phone"]) < 1.0, (right, left)
        assert sorted(right["arm"]) == pytest.approx(sorted(-a for a in left["arm"]), abs=1.0)


def test_the_place_choice_says_which_exercises_each_place_measures(module_server, phone, shots):
    """Found walking a patient's path at 390 px: the welcome lists four exercises ("Today:
    Bend the elbow, Turn the palm, Raise the arm forward, Raise the arm to the side"), then
    "Where will you wear the phone?" offered two near-identical pictures, "On my forearm"
    and "On my upper arm", saying nothing of what either measures; the forearm session ran
    "Exercise 1 of 2" and ended "Session finished", the other two never named. Each choice
    now names the exercises done with the phone there."""
    api = module_server.client("alice")
    token = api.device(api.patient("Place Choice")["id"], "phone")["token"]
    phone.goto(f"{module_server.url}/kit#token={token}")
    phone.click("#start")
    sync_api.expect(phone.locator("#segment-forearm")).to_be_visible()
    phone.screenshot(path=str(shots / "place-choice.png"))
    forearm = phone.locator("#segment-forearm").inner_text()
    upper = phone.locator("#segment-upper_arm").inner_text()
    print(f"\nforearm: {forearm!r}\nupper arm: {upper!r}")
    assert "Bend the elbow" in forearm and "Turn the palm" in forearm
    assert "Raise the arm" not in forearm
    assert "Raise the arm forward" in upper and "Raise the arm to the side" in upper
    assert "Bend the elbow" not in upper
    # all of it on the phone's width, nothing cut off to the side
    assert phone.evaluate("document.documentElement.scrollWidth") <= 390
    phone.evaluate("localStorage.clear()")
