"""The phone kit says where the patient stands this week ("This week: 1 of 3 days done"),
and it is the therapist's count: device-today's ``this_week`` comes from the adherence
rule (``adherence.week_days``), and the therapist's patient page shows the same days in
its weeks table. A real server on a simulated calendar in the clinic's time zone
(Europe/Zurich, UTC+1: its clock is replaced in the server process, ``server/clock.py``),
sessions streamed by the kit emulator naming the program in ``hello`` (real WebSockets),
the kit page and the therapist's page in Debian's chromium at 390 and 1280 px.

Days: Tuesday of one week; Sunday 23:30 in the clinic (22:30 UTC, that week); Sunday
23:30 UTC (Monday 00:30 in the clinic: the next week); Monday again (one day, two
sessions). The finished screen asks again once the session is all sent: the page's own
stream is stood in for (its session is stored by the emulator with the same link), the
rest of the page is real."""

from __future__ import annotations

import asyncio
import re
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, date, datetime
from zoneinfo import ZoneInfo

import numpy as np
import pytest
from armtrack.estimator.recording import Mark, Pose, Recording, SensorStream
from armtrack.server.emulator import KitEmulator
from browser_helpers import chromium, first_page, need_browser, screenshots_folder, sign_in_as
from server_support import SIMULATED_CLOCK_PREAMBLE, Zygote, ZygoteServerProcess

sync_api = need_browser()

ZONE = ZoneInfo("Europe/Zurich")
NAME = "After the fracture"
PROGRAM = {"name": NAME, "start_date": "2026-11-23", "exercises": [
    {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 3},
    {"exercise": "pronation", "sets": 1, "repetitions": 6, "days_per_week": 2}]}

def clinic(day: date, hour: int, minute: int = 0) -> datetime:
    """``hour:minute`` of ``day`` in the clinic, as UTC."""
    return datetime(day.year, day.month, day.day, hour, minute, tzinfo=ZONE).astimezone(UTC)


def short_recording() -> Recording:
    """A forearm phone's 1.5 s: enough to be a session; its days are what is counted."""
    rng = np.random.default_rng(7)
    t = np.arange(90) / 60
    return Recording(side="right", height_m=1.7, rate_hz=60.0,
                     sensors={"forearm": SensorStream(t, rng.normal(0, 3, (90, 3)),
                                                      rng.normal(0, 1, (90, 3)), None)},
                     calibration=(Pose("npose", 0.0, 0.3),),
                     marks=(Mark(0.5, "exercise:elbow_flexion"),
                            Mark(1.2, "end:exercise:elbow_flexion")))


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("kit-week")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote,
                                 env={"ARMTRACK_CLINIC_TIMEZONE": "Europe/Zurich"})
    server.create_user("alice")
    server.start()
    try:
        alice = server.client("alice")
        patient = alice.patient("Ada Week")
        device = alice.device(patient["id"], "Ada's phone")
        now_file.write_text(clinic(date(2026, 11, 23), 8).isoformat())
        made = alice.http.post(f"/api/patients/{patient['id']}/programs", json=PROGRAM)
        assert made.status_code == 201, made.text
        yield {"server": server, "alice": alice, "patient": patient, "token": device["token"],
               "program": made.json(), "now": now_file,
               "shots": screenshots_folder(tmp_path_factory, "kit-week-shots")}
    finally:
        server.stop()
        zygote.close()


def session_at(world, moment: datetime) -> int:
    """A session of the program started at ``moment`` (the server's clock set to it)."""
    world["now"].write_text(moment.isoformat())
    kit = KitEmulator(short_recording(), world["server"].ws_url, world["token"], speed=0,
                      rows_per_message=30,
                      hello_extra={"extensions": ["programs/1"], "program": NAME})
    with ThreadPoolExecutor(1) as pool:  # Playwright's sync API holds this thread's loop
        return pool.submit(asyncio.run, kit.run()).result(timeout=120).session


def this_week(world, moment: datetime) -> dict:
    world["now"].write_text(moment.isoformat())
    answer = world["alice"].http.get("/api/device/today",
                                     headers={"Authorization": f"Bearer {world['token']}"})
    assert answer.status_code == 200, answer.text
    return answer.json()["this_week"]


def adherence_days(world) -> dict[str, tuple[int, int]]:
    weeks = world["alice"].http.get(
        f"/api/programs/{world['program']['id']}/adherence").json()["weeks"]
    return {w["week"]: (w["done"]["days"], w["prescribed"]["days"]) for w in weeks}


def numbers(text: str) -> tuple[int, int]:
    """(done, asked) of the phone's words."""
    if found := re.search(r"(\d+) of (\d+) days? done", text):
        return int(found[1]), int(found[2])
    found = re.search(r"done all (\d+) days this week", text)
    assert found, text
    return int(found[1]), int(found[1])


def phone_week(page, world, shot: str) -> str:
    """The kit page's welcome (opened afresh) in ``page``: its week line, a screenshot."""
    page.goto(f"{world['server'].url}/kit#token={world['token']}")
    line = page.locator("#this-week")
    sync_api.expect(line).to_be_visible(timeout=30_000)
    page.screenshot(path=str(world["shots"] / shot), full_page=True)
    return line.inner_text()


def test_the_phone_says_this_weeks_days_as_the_therapist_counts_them(world):
    monday, week2 = date(2026, 11, 23), date(2026, 11, 30)
    # before any session: none of 3 (elbow 3 days a week, the palm 2: the most, 3)
    assert this_week(world, clinic(monday, 9)) == {
        "week": "2026-W48", "monday": "2026-11-23", "days_done": 0, "days_asked": 3,
        "today_done": False, "shortened": None, "changed_on": None}
    with (sync_api.sync_playwright() as playwright,
          chromium(playwright, 390, 844, phone=True) as narrow,
          chromium(playwright, 1280, 900) as wide):
        phone, desk = first_page(narrow), first_page(wide)
        said = phone_week(phone, world, "w1-welcome-none-390.png")
        assert said == "This week: 0 of 3 days done. Today is a good day to start."

        session_at(world, clinic(date(2026, 11, 24), 10))         # Tuesday
        session_at(world, clinic(date(2026, 11, 29), 23, 30))     # Sunday 23:30, 22:30 UTC
        crossing = datetime(2026, 11, 29, 23, 30, tzinfo=UTC)     # Monday 00:30 in Zurich
        session_at(world, crossing)
        session_at(world, clinic(week2, 11))                      # the same Monday again
        assert this_week(world, clinic(date(2026, 11, 29), 23, 45))["days_done"] == 2
        now = this_week(world, clinic(week2, 12))
        assert now == {"week": "2026-W49", "monday": "2026-11-30", "days_done": 1,
                       "days_asked": 3, "today_done": True, "shortened": None,
                       "changed_on": None}
        # the therapist's adherence, by the same rule: W48 Tuesday and Sunday, W49 Monday
        assert adherence_days(world) == {"2026-W48": (2, 3), "2026-W49": (1, 3)}

        said = phone_week(phone, world, "w2-welcome-390.png")
        assert said == "This week: 1 of 3 days done."
        assert phone_week(desk, world, "w3-welcome-1280.png") == said

        # the therapist's page shows the same days beside the week (its weeks table)
        for width, context in ((1280, wide), (390, narrow)):
            page = context.new_page()
            sign_in_as(page, world["server"].url, "alice")
            page.goto(f"{world['server'].url}/patients/{world['patient']['id']}")
            row = page.locator('table.adherence tr[data-week="2026-W49"]')
            sync_api.expect(row).to_be_visible(timeout=30_000)
            days = row.locator("td").nth(1).inner_text()
            page.locator("details.weeks").screenshot(
                path=str(world["shots"] / f"w4-therapist-weeks-{width}.png"))
            page.close()
            assert days.split()[-3:] == ["1", "/", "3"], days  # "Days" label at 390
            assert numbers(said) == (1, 3)

        # the finished screen (the phone still on its welcome of "1 of 3"): this week's
        # count asked again once the session is stored
        stored = session_at(world, clinic(date(2026, 12, 1), 9))  # Tuesday's session
        phone.evaluate("""(session) => {
            kit.stream = { state: { finished: true, session }, connected: true, unsent: 0,
                           finish: async () => {}, keepTail() {} };
            finished();
        }""", stored)
        line = phone.locator("#this-week")
        sync_api.expect(line).to_have_text("This week: 2 of 3 days done.", timeout=30_000)
        phone.screenshot(path=str(world["shots"] / "w5-finished-390.png"), full_page=True)
        assert adherence_days(world)["2026-W49"] == (2, 3)

        session_at(world, clinic(date(2026, 12, 2), 9))  # Wednesday: all three days
        this_week(world, clinic(date(2026, 12, 2), 12))
        said = phone_week(desk, world, "w6-welcome-all-1280.png")
        assert said == "You have done all 3 days this week — well done."
        assert phone_week(phone, world, "w7-welcome-all-390.png") == said
        assert adherence_days(world)["2026-W49"] == numbers(said) == (3, 3)


def test_a_week_the_program_starts_in_says_why_it_asks_fewer_days(world):
    """A program of 5 days a week prescribed on a Saturday asks 2 days of that week (the
    therapist's adherence: its active days). The welcome said "5 days a week" and then
    "This week: 0 of 2 days done" with no reason (user20's walk at 390 px): it now says
    the program started on Saturday."""
    saturday = date(2026, 12, 5)
    world["now"].write_text(clinic(saturday, 10).isoformat())
    alice = world["alice"]
    patient = alice.patient("Bea Saturday")
    token = alice.device(patient["id"], "Bea's phone")["token"]
    made = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "From Saturday", "start_date": saturday.isoformat(), "exercises": [
            {"exercise": "elbow_flexion", "sets": 2, "repetitions": 10, "days_per_week": 5}]})
    assert made.status_code == 201, made.text
    answer = alice.http.get("/api/device/today", headers={"Authorization": f"Bearer {token}"})
    week = answer.json()["this_week"]
    assert (week["days_done"], week["days_asked"]) == (0, 2)
    assert week["shortened"] == {"starts_on": "2026-12-05", "ends_on": None}
    expected = ("This week: 0 of 2 days done (your program started on Saturday). "
                "Today is a good day to start.")
    with sync_api.sync_playwright() as playwright:
        for width, height in ((390, 844), (1280, 900)):
            with chromium(playwright, width, height, phone=width < 500) as context:
                page = first_page(context)
                assert phone_week(page, {**world, "token": token},
                                  f"w8-started-saturday-{width}.png") == expected
                sync_api.expect(page.locator("body")).to_contain_text("5 days a week")


def test_a_change_in_the_week_says_it_counts_from_the_next_week(world):
    """A program of 6 days a week that began on Wednesday asks 5 days of that week; a
    change to 3 days a week saved on Thursday leaves the week on the version it began with
    (the adherence rule: the version in force on Monday, for a first week the first). The
    phone's list then says "3 days a week" beside "0 of 5 days": it says both reasons,
    and the therapist's weeks table says them beside the week's days."""
    wednesday, thursday = date(2026, 12, 2), date(2026, 12, 3)
    alice = world["alice"]
    patient = alice.patient("Cem Change")
    token = alice.device(patient["id"], "Cem's phone")["token"]
    world["now"].write_text(clinic(wednesday, 8).isoformat())
    elbow = {"exercise": "elbow_flexion", "sets": 1, "repetitions": 5}
    made = alice.http.post(f"/api/patients/{patient['id']}/programs", json={
        "name": "From Wednesday", "start_date": wednesday.isoformat(),
        "exercises": [{**elbow, "days_per_week": 6}]})
    assert made.status_code == 201, made.text
    world["now"].write_text(clinic(thursday, 9).isoformat())
    changed = alice.http.put(f"/api/programs/{made.json()['id']}", json={
        "start_date": wednesday.isoformat(), "exercises": [{**elbow, "days_per_week": 3}]})
    assert changed.status_code == 200, changed.text
    week = this_week({**world, "token": token}, clinic(thursday, 10))
    assert (week["days_asked"], week["changed_on"]) == (5, "2026-12-03"), week
    expected = ("This week: 0 of 5 days done (your program started on Wednesday; its "
                "change of Thursday counts from next week). Today is a good day to start.")
    with (sync_api.sync_playwright() as playwright,
          chromium(playwright, 390, 844, phone=True) as narrow,
          chromium(playwright, 1280, 900) as wide):
        for width, context in ((390, narrow), (1280, wide)):
            page = first_page(context)
            assert phone_week(page, {**world, "token": token},
                              f"c1-changed-{width}.png") == expected
            sync_api.expect(page.locator("body")).to_contain_text("3 days a week")
            sign_in_as(page, world["server"].url, "alice")
            page.goto(f"{world['server'].url}/patients/{patient['id']}")
            row = page.locator('table.adherence tr[data-week="2026-W49"]')
            sync_api.expect(row).to_be_visible(timeout=30_000)
            page.locator("details.weeks").screenshot(
                path=str(world["shots"] / f"c2-therapist-weeks-{width}.png"))
            cells = row.locator("td")
            assert cells.nth(1).inner_text().split()[-3:] == ["0", "/", "5"]
            why = row.locator(".week-why").inner_text()
            began, on = page.evaluate("() => [fmtDay('2026-12-02'), fmtDay('2026-12-03')]")
            assert why == f"began {began} · changed {on}: counts from the next week", why
