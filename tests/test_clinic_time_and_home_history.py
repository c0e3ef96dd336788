"""Times a clinic reads, and what a patient at home sees of their own sessions, on a real
server (its clock simulated: ``server/clock.py``), real WebSockets (``server/emulator``),
real processing, and Debian's chromium at 390 and 1280 px.

1. The session PDF wrote "22:39 UTC" (24 h) where the pages wrote "10:39 PM": the clinic's
   clock (``ARMTRACK_CLINIC_CLOCK``) now sets both, in the clinic's zone, and the PDF says
   which zone once, and names the program the session followed.
2. The phone showed only the last session kept on that phone (a new phone: none), and
   "Changed by your therapist" said not when: device-today now carries the link's own
   patient's recent sessions (the finished screen's words) and the version's date."""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace
from zoneinfo import ZoneInfo

import pytest
from armtrack.server.emulator import KitEmulator
from browser_helpers import chromium, first_page, need_browser, screenshots_folder, sign_in_as
from server_support import SIMULATED_CLOCK_PREAMBLE, Zygote, ZygoteServerProcess
from test_programs_followed import Planned, recording_of

pytestmark = pytest.mark.slow

ZONE = ZoneInfo("America/New_York")
PROGRAM = {"name": "Elbow at home", "exercises": [
    {"exercise": "elbow_flexion", "sets": 2, "repetitions": 5, "days_per_week": 5,
     "target_min_deg": 0, "target_max_deg": 110}]}


def _minute(moment: datetime) -> datetime:
    return moment.replace(second=0, microsecond=0)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Ada follows "Elbow at home" (version 2, changed two days ago) in one session 3 h
    ago and does an unprogrammed one 50 h ago; Bob, another patient of the same
    therapist, has a session of his own."""
    folder = tmp_path_factory.mktemp("clinic-time")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote, env={
        "ARMTRACK_CLINIC_TIMEZONE": "America/New_York", "ARMTRACK_CLINIC_CLOCK": "12h"})
    server.create_user("alice")
    server.start()

    def set_now(moment: datetime | None) -> None:
        now_file.write_text(moment.isoformat() if moment else "")

    real_now = datetime.now(UTC)
    try:
        alice = server.client("alice")
        ada = alice.patient("Ada Home", side="right")
        bob = alice.patient("Bob Other", side="right")
        ada_phone = alice.device(ada["id"], "Ada's phone")
        bob_phone = alice.device(bob["id"], "Bob's phone")
        start_day = (real_now - timedelta(days=5)).astimezone(ZONE).date().isoformat()
        set_now(real_now - timedelta(days=4))
        made = alice.http.post(f"/api/patients/{ada['id']}/programs",
                               json={**PROGRAM, "start_date": start_day})
        assert made.status_code == 201, made.text
        program = made.json()
        changed_at = _minute(real_now - timedelta(days=2, hours=1))
        set_now(changed_at)
        v2 = alice.http.put(f"/api/programs/{program['id']}", json={
            "start_date": start_day, "exercises": [
                {**PROGRAM["exercises"][0], "repetitions": 6}]})
        assert v2.status_code == 200, v2.text

        def stream(token, at, planned, seed, extra=None):
            set_now(at)
            kit = KitEmulator(recording_of(planned, seed=seed), server.ws_url, token,
                              speed=0, rows_per_message=50, hello_extra=extra or {})
            stats = asyncio.run(kit.run())
            session = alice.wait_processed(stats.session, timeout=240)
            assert session["processed"], session
            return session

        older = stream(ada_phone["token"], _minute(real_now - timedelta(hours=50)),
                       Planned(None, {"elbow_flexion": [(4, 90.0)]}), seed=301)
        followed = stream(ada_phone["token"], _minute(real_now - timedelta(hours=3)),
                          Planned(None, {"elbow_flexion": [(6, 100.0), (6, 100.0)]}),
                          seed=302, extra={"extensions": ["programs/1"],
                                           "program": "Elbow at home"})
        bobs = stream(bob_phone["token"], _minute(real_now - timedelta(hours=2)),
                      Planned(None, {"elbow_flexion": [(3, 70.0)]}), seed=303)
        set_now(None)  # the real clock from here on
        yield SimpleNamespace(server=server, alice=alice, ada=ada, bob=bob,
                              ada_phone=ada_phone, bob_phone=bob_phone, program=program,
                              changed_at=changed_at, older=older, followed=followed,
                              bobs=bobs)
    finally:
        server.stop()
        zygote.close()


def _start(session: dict) -> datetime:
    return datetime.fromisoformat(session["started_at"]).astimezone(ZONE)


def _pdf_first_page(pdf: bytes, path) -> str:
    path.write_bytes(pdf)
    subprocess.run(["pdftoppm", "-png", "-r", "70", "-f", "1", "-l", "2", str(path),
                    str(path.with_suffix(""))], check=True, timeout=120)
    return subprocess.run(["pdftotext", "-layout", str(path), "-"], capture_output=True,
                          text=True, check=True).stdout


def test_the_session_pdf_writes_the_clinics_time_as_the_pages_do_and_names_the_program(
        world, tmp_path_factory):
    if shutil.which("pdftoppm") is None or shutil.which("pdftotext") is None:
        pytest.skip("pdftoppm/pdftotext (Debian poppler-utils) are missing")
    sync_api = need_browser()
    shots = screenshots_folder(tmp_path_factory, "clinic-time")
    session = world.followed
    answer = world.alice.http.get(f"/api/sessions/{session['id']}/report.pdf")
    assert answer.status_code == 200, answer.text[:300]
    text = _pdf_first_page(answer.content, shots / "session.pdf")
    flat = " ".join(text.split())
    first_page_text = " ".join(text.split("\f")[0].split())
    start = _start(session)
    clock = f"{start:%I:%M %p}"  # the clinic's 12-hour clock, as the pages write it
    print(f"\nstarted {session['started_at']} = {start:%a %d %b %Y} {clock} {start:%Z}")
    print(first_page_text[:900])
    # the clinic's time, in its clock, and the zone said (once on the summary)
    assert f"{start.day} {start:%b %Y}, {clock} {start:%Z}" in first_page_text
    assert first_page_text.count(f"{start:%Z}") == 1, first_page_text
    assert "UTC" not in flat
    # the program the session followed, with its version
    assert "Program Elbow at home, version 2" in first_page_text

    # the pages, in a browser elsewhere (Tokyo), say the same clock time and zone
    from playwright.sync_api import sync_playwright
    with sync_playwright() as playwright:
        # an English browser in Britain writes 24 h by itself: the clinic's clock wins
        for width, language in ((390, "en-US"), (1280, "en-GB")):
            with chromium(playwright, width, phone=width < 500, timezone_id="Asia/Tokyo",
                          locale=language) as context:
                page = first_page(context)
                sign_in_as(page, world.server.url, "alice")
                page.goto(f"{world.server.url}/sessions/{session['id']}")
                facts = page.locator("#facts")
                # the session's own page writes its seconds too: 08:30:00 PM
                # (en-GB names the zone GMT-5 where en-US and the PDF say EST)
                zone = f"{start:%Z}" if language == "en-US" else ""
                said = re.compile(rf"{start:%I:%M}(:\d\d)? {start:%p}\s+{zone}", re.I)
                sync_api.expect(facts).to_have_text(said)
                page.screenshot(path=str(shots / f"session-{width}.png"), full_page=True)
                print(f"{width} px, {language}: {facts.inner_text()[:200]!r}")


def test_a_24_hour_clinic_reads_24_hours_in_pdf_and_pages():
    """The default clock (24 h): the summary's time reads 22:39, not 10:39 PM."""
    from armtrack.server.reports.pdf_summary import local

    moment = datetime(2026, 12, 3, 22, 39, tzinfo=UTC)
    assert local(moment, ZoneInfo("UTC")) == "Thu 3 Dec 2026, 22:39 UTC"
    assert local(moment, ZoneInfo("UTC"), clock="12h") == "Thu 3 Dec 2026, 10:39 PM UTC"
    assert (local(moment, ZoneInfo("Europe/Paris"), clock="24h")
            == "Thu 3 Dec 2026, 23:39 CET")


def test_the_progress_pdf_says_the_clinics_zone_once(world, tmp_path):
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (Debian poppler-utils) is missing")
    answer = world.alice.http.get(f"/api/patients/{world.ada['id']}/progress.pdf")
    assert answer.status_code == 200, answer.text[:300]
    text = _pdf_first_page(answer.content, tmp_path / "progress.pdf")
    flat = " ".join(text.split())
    print(flat[:400])
    assert "(UTC)" not in flat
    assert flat.count("America/New_York") == 1, flat
    assert "the clinic's day (America/New_York)" in flat, flat


def _today(server, token: str):
    import httpx
    return httpx.get(server.url + "/api/device/today",
                     headers={"Authorization": f"Bearer {token}"}, timeout=60)


def test_device_today_gives_the_patient_their_own_recent_sessions(world):
    answer = _today(world.server, world.ada_phone["token"])
    assert answer.status_code == 200, answer.text
    today = answer.json()
    recent = today["recent"]
    print("\n" + "\n".join(str(r) for r in recent))
    # newest first, Ada's two sessions only (Bob's is newer than both)
    assert [r["session_id"] for r in recent] == [world.followed["id"], world.older["id"]]
    assert world.bobs["id"] not in [r["session_id"] for r in recent]
    report = world.alice.http.get(f"/api/sessions/{world.followed['id']}/report").json()
    reps = sum(a["repetitions"] for e in report["exercises"] if e["name"] == "elbow_flexion"
               for a in e["angles"] if a["angle"] == "elbow_flexion")  # both sets
    first = recent[0]
    assert (datetime.fromisoformat(first["started_at"])
            == datetime.fromisoformat(world.followed["started_at"]))
    assert first["program"] == {"name": "Elbow at home", "version": 2}
    (done,) = first["exercises"]
    assert done["name"] == "elbow_flexion" and done["title"] == "Bend the elbow"
    assert done["angle"] == "elbow_flexion"  # the kit words a both-ways range by it
    assert done["repetitions"] == reps == 12, (done, reps)
    assert done["prescribed"] == 12  # version 2: 2 sets of 6
    assert done["target"] == {"min_deg": 0.0, "max_deg": 110.0, "from": "program"}
    assert 85 < done["max_deg"] < 115 and -15 < done["min_deg"] < 15, done
    # the session without a program: the catalogue's count, the catalogue's band
    assert recent[1]["program"] is None
    assert recent[1]["exercises"][0]["prescribed"] == 10
    assert recent[1]["exercises"][0]["repetitions"] == 4
    # when the therapist changed the program
    changed = datetime.fromisoformat(today["program"]["changed_at"])
    assert changed == world.changed_at, (changed, world.changed_at)

    bob = _today(world.server, world.bob_phone["token"]).json()
    assert [r["session_id"] for r in bob["recent"]] == [world.bobs["id"]]
    assert "Ada" not in str(bob) and "Elbow at home" not in str(bob)
    # a revoked link gets nothing
    revoked = world.alice.device(world.ada["id"], "old phone")
    assert world.alice.http.delete(f"/api/devices/{revoked['id']}").status_code == 204
    gone = _today(world.server, revoked["token"])
    assert gone.status_code == 401 and "recent" not in gone.text


def _when(moment: datetime, now: datetime) -> str:
    """kit.js's day words for a moment, in the phone's zone (the clinic's here)."""
    days = (now.astimezone(ZONE).date() - moment.astimezone(ZONE).date()).days
    if days == 0:
        return "today"
    if days == 1:
        return "yesterday"
    local = moment.astimezone(ZONE)
    return f"{local:%A}, {local:%b} {local.day}"


@pytest.mark.parametrize("width", [390, 1280])
def test_a_new_phone_shows_the_patients_recent_sessions_and_when_the_program_changed(
        world, width, tmp_path_factory):
    sync_api = need_browser()
    shots = screenshots_folder(tmp_path_factory, "home-history")
    from playwright.sync_api import sync_playwright
    with sync_playwright() as playwright, chromium(
            playwright, width, phone=width < 500, timezone_id="America/New_York",
            locale="en-US") as context:
        phone = first_page(context)
        phone.goto(f"{world.server.url}/kit#token={world.ada_phone['token']}")
        sync_api.expect(phone.locator("#program-name")).to_have_text("Elbow at home")
        now = datetime.now(UTC)
        version = phone.locator("#program-version")
        sync_api.expect(version).to_have_text(
            "Changed by your therapist "
            + ("today" if _when(world.changed_at, now) == "today"
               else ("yesterday" if _when(world.changed_at, now) == "yesterday"
                     else "on " + _when(world.changed_at, now))))
        recent = phone.locator("#recent .last")
        sync_api.expect(recent).to_have_count(2)
        phone.screenshot(path=str(shots / f"kit-welcome-{width}.png"), full_page=True)
        texts = recent.all_inner_texts()
        print("\n" + "\n---\n".join(texts))
        first, second = texts
        assert first.startswith(f"Last time, {_when(_start(world.followed), now)}")
        assert re.search(r"Bend the elbow: 12 of 12 repetitions · from -?\d+° to \d+° "
                         r"\(target 0° to 110°\)", first), first
        older = _when(_start(world.older), now)
        assert second.startswith(older[0].upper() + older[1:]), (second, older)
        assert "Bend the elbow: 4 of 10 repetitions" in second
        assert "Bob" not in phone.locator("#screen").inner_text()
