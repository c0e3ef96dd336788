"""A therapist reviews last week: a session's page showed "Today's sessions" with today's
sessions — on Thursday's session, Friday's chip and not Thursday's own (found reviewing a
week of home use, 390 and 1280 px). The strip is the session's day's: "Today's sessions"
on a session of today, "Sessions of <its day>" on an older one, the session in view among
them. A real server on a simulated calendar (``server/clock.py``), real WebSockets,
Debian's chromium."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace

import pytest
from armtrack.server.emulator import KitEmulator
from browser_helpers import need_browser, page_at, sign_in_as
from server_support import SIMULATED_CLOCK_PREAMBLE, Zygote, ZygoteServerProcess
from test_programs_followed import Planned, recording_of

sync_api = need_browser()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Two sessions yesterday at 10:00 and 10:30 (UTC, the clinic's zone), one today."""
    folder = tmp_path_factory.mktemp("day-sessions")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote)
    server.create_user("alice")
    server.start()
    try:
        alice = server.client("alice")
        patient = alice.patient("Week Review")
        token = alice.device(patient["id"], "phone")["token"]
        real_now = datetime.now(UTC)
        yesterday = (real_now - timedelta(days=1)).replace(hour=10, minute=0, second=0,
                                                           microsecond=0)
        today = real_now - timedelta(minutes=2)

        def stream(at: datetime, seed: int) -> int:
            now_file.write_text(at.isoformat())
            kit = KitEmulator(recording_of(Planned(at, {"elbow_flexion": [(3, 90.0)]}),
                                           seed=seed), server.ws_url, token, speed=0,
                              rows_per_message=50)
            stats = asyncio.run(kit.run())
            return alice.wait_processed(stats.session, timeout=240)["id"]

        ids = [stream(yesterday, 1), stream(yesterday + timedelta(minutes=30), 2),
               stream(today, 3)]
        now_file.write_text("")
        yield SimpleNamespace(server=server, ids=ids, yesterday=yesterday)
    finally:
        server.stop()
        zygote.close()


@pytest.mark.parametrize("width", [390, 1280])
def test_a_past_sessions_page_lists_its_own_days_sessions(world, width):
    first, second, todays = world.ids
    day = world.yesterday
    with page_at(width) as page:
        sign_in_as(page, world.server.url, "alice")
        page.goto(f"{world.server.url}/sessions/{first}")
        card = page.locator("#day-history")
        sync_api.expect(card.locator(".day-session")).to_have_count(2, timeout=30_000)
        heading = card.locator("h2").inner_text()
        chips = card.locator(".day-session").evaluate_all(
            "els => els.map(e => e.dataset.session)")
        print(f"\n{width} px, session {first} of {day:%a %d %b}: {heading!r}, chips {chips}")
        assert heading == f"Sessions of {day:%a}, {day:%b} {day.day}", heading
        assert chips == [str(first), str(second)]
        sync_api.expect(card.locator(".current")).to_have_attribute(
            "data-session", str(first))

        page.goto(f"{world.server.url}/sessions/{todays}")
        sync_api.expect(card.locator(".day-session")).to_have_count(1, timeout=30_000)
        assert card.locator("h2").inner_text() == "Today's sessions"
        sync_api.expect(card.locator(".current")).to_have_attribute(
            "data-session", str(todays))


@pytest.fixture(scope="module")
def busy_week(tmp_path_factory):
    """Two sessions on a day three days ago, then 31 sessions the day after (a patient
    who did many short sessions): the first day's lie past the newest 30 the page read."""
    from test_security_session_flood import HELLO

    folder = tmp_path_factory.mktemp("day-sessions-busy")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote,
                                 env={"ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR": "100"})
    server.create_user("alice")
    server.start()
    try:
        from websockets.asyncio.client import connect

        alice = server.client("alice")
        patient = alice.patient("Many Sessions")
        token = alice.device(patient["id"], "kit")["token"]
        day = (datetime.now(UTC) - timedelta(days=3)).replace(hour=10, minute=0, second=0,
                                                              microsecond=0)

        async def session_at(at: datetime) -> int:
            now_file.write_text(at.isoformat())
            async with connect(server.ws_url, additional_headers={
                    "Authorization": f"Bearer {token}"}) as ws:
                await ws.send(json.dumps(HELLO))
                ready = json.loads(await asyncio.wait_for(ws.recv(), 10))
                assert ready["type"] == "ready", ready
                await ws.send(json.dumps({"type": "bye"}))
                return ready["session"]

        async def all_sessions() -> list[int]:
            ids = [await session_at(day), await session_at(day + timedelta(minutes=30))]
            for k in range(31):
                ids.append(await session_at(day + timedelta(days=1, minutes=k)))
            return ids

        ids = asyncio.run(all_sessions())
        now_file.write_text("")
        yield SimpleNamespace(server=server, ids=ids, day=day)
    finally:
        server.stop()
        zygote.close()


def test_a_days_sessions_past_the_newest_30_are_listed(busy_week):
    """The strip read the patient's newest 30 summaries and kept those of the session's
    day: a day with 31 sessions after it had no strip at all on its sessions' pages. Only
    that day's summaries are asked for (and a neighbour on either side, should a session
    begin meanwhile): each is built from the session's report (0.36 s for a 15-minute
    session on a cold cache), and reading back every newer session's (31 here, up to 300)
    to show one day's few cost the server the reports of them all."""
    first, second = busy_week.ids[:2]
    day = busy_week.day
    with page_at(1280) as page:
        summarised: list[int] = []  # the sessions whose summaries the page asked for
        page.on("response", lambda r: summarised.extend(s["id"] for s in r.json())
                if "/summaries" in r.url and r.ok else None)
        sign_in_as(page, busy_week.server.url, "alice")
        page.goto(f"{busy_week.server.url}/sessions/{first}")
        card = page.locator("#day-history")
        page.wait_for_timeout(3000)  # the strip comes with the page's first reads
        chips = card.locator(".day-session").evaluate_all(
            "els => els.map(e => e.dataset.session)")
        print(f"\nsession {first} of {day:%a %d %b}, 31 sessions after its day: chips {chips}")
        sync_api.expect(card.locator(".day-session")).to_have_count(2, timeout=30_000)
        assert card.locator("h2").inner_text() == f"Sessions of {day:%a}, {day:%b} {day.day}"
        chips = card.locator(".day-session").evaluate_all(
            "els => els.map(e => e.dataset.session)")
        assert chips == [str(first), str(second)]
    print(f"summaries asked for: {len(summarised)}, sessions {sorted(set(summarised))}")
    assert set(summarised) <= set(busy_week.ids[:3]), sorted(set(summarised))
