"""A kit's day (``ARMTRACK_MAX_KIT_SAMPLES_PER_DAY``: rows of its sessions created in the
last 24 hours) ages while one of its sockets stays open for more than a day.

The server counts a kit's day from the database when its first stream opens, then in
memory as its streams store rows (5e51af9). That count never aged: a kit whose socket
stayed open past a day still held the first day's rows against itself, and its new
sessions were refused as if the day were spent. Real server on a clock the test moves
(``server/clock.py`` replaced in the server process, as test_programs_followed does),
real WebSocket clients, real database file; no 24-h wait."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime, timedelta

import pytest
from server_support import SIMULATED_CLOCK_PREAMBLE, Zygote, ZygoteServerProcess
from test_security_kit_quota import samples, stored
from test_security_session_flood import hello

LIMIT = 3000
SETTING = "ARMTRACK_MAX_KIT_SAMPLES_PER_DAY"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("kit-day")
    now_file = folder / "now.txt"
    zygote = Zygote(SIMULATED_CLOCK_PREAMBLE.format(path=str(now_file)))
    server = ZygoteServerProcess(folder / "server", zygote, env={SETTING: str(LIMIT)})
    server.create_user("alice")
    server.start()
    try:
        yield server, now_file
    finally:
        server.stop()
        zygote.close()


async def send_all(ws, sizes: list[int], first_seq: int = 0, t0: float = 0.0
                   ) -> dict[int, str]:
    """Send messages of ``sizes`` rows; wait for an answer to each: seq → the reason of
    each refused one."""
    refused: dict[int, str] = {}
    t = t0
    for k, rows in enumerate(sizes):
        await ws.send(samples(first_seq + k, t, rows))
        t += rows / 50
    last = first_seq + len(sizes) - 1
    answered: set[int] = set()
    while last not in answered:
        message = json.loads(await asyncio.wait_for(ws.recv(), 30))
        if message["type"] == "error":
            refused[message["seq"]] = message["reason"]
            answered.add(message["seq"])
        elif message["type"] == "ack":
            answered.update(range(first_seq, message["seq"] + 1))
    return refused


def test_a_socket_open_past_a_day_does_not_hold_the_first_days_rows(world):
    server, now_file = world
    alice = server.client("alice")
    token = alice.device(alice.patient("Long Socket")["id"], "kit")["token"]
    start = datetime.now(UTC)
    now_file.write_text(start.isoformat())

    async def run() -> dict:
        # day 1: session A stores 2,000 rows; its socket stays open
        ws_a, ready_a = await hello(server, token)
        assert ready_a["type"] == "ready", ready_a
        refused_a1 = await send_all(ws_a, [100] * 20)
        # 25 h later, on the same open socket and a new one
        now_file.write_text((start + timedelta(hours=25)).isoformat())
        ws_b, ready_b = await hello(server, token)
        assert ready_b["type"] == "ready", ready_b
        refused_b = await send_all(ws_b, [100] * 15)          # 1,500 rows of day 2
        refused_a2 = await send_all(ws_a, [100] * 5, 20, 40.0)  # 500 more into A
        # day 2 still has its limit: 1,500 + 1,600 would pass 3,000
        refused_b2 = await send_all(ws_b, [800, 800], 15, 30.0)
        for ws in (ws_a, ws_b):
            await ws.send(json.dumps({"type": "bye"}))
            async for _ in ws:
                pass
        return {"a": ready_a["session"], "a1": refused_a1,
                "b": refused_b, "a2": refused_a2, "b2": refused_b2,
                "session_b": ready_b["session"]}

    got = asyncio.run(run())
    print(f"\nrefused on day 1: {got['a1']}; day 2, new session: {got['b']}; "
          f"day 2, the open socket's session: {got['a2']}; day 2 past its limit: {got['b2']}")
    print(f"stored: A {stored(server, got['a'])}, B {stored(server, got['session_b'])}")
    assert not got["a1"]
    assert not got["b"], "day 2's new session was refused with day 1's rows"
    assert not got["a2"], "the open session's rows of day 2 were refused"
    assert stored(server, got["session_b"]) == 1500 + 800
    assert stored(server, got["a"]) == 2500
    assert list(got["b2"]) == [16] and SETTING in got["b2"][16]


def test_a_kits_day_is_counted_right_from_threads_at_once(monkeypatch):
    """A kit's day is read on database threads (a hello's ``_day_left``: several kits'
    hellos at once) while its streams count on the event loop: ``KitDay.total`` takes the
    sessions that left the window out of its heap, and two threads doing it at once took
    out each other's entries (a session still in the window dropped from the count, or one
    gone counted on: the day over- or under-told). Three threads each read the total of a
    day whose older half just left the window; the count must be the database's."""
    import sys
    import threading

    from armtrack.server import clock
    from armtrack.server.kit.daily_samples import WINDOW, KitDay

    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch as often as they can
    wrong = []
    try:
        for _ in range(10):
            base = datetime.now(UTC)
            monkeypatch.setattr(clock, "now", lambda at=base: at)
            n = 20000  # sessions of one row each, one a second
            born = {i: (base - timedelta(seconds=n - i), 1) for i in range(n)}
            day = KitDay(born)
            later = base + WINDOW - timedelta(seconds=n // 2)  # the older half has left
            monkeypatch.setattr(clock, "now", lambda at=later: at)
            start, errors = threading.Barrier(3), []

            def read(day=day, start=start, errors=errors):
                start.wait()
                try:
                    day.total()
                except Exception as exc:  # what a race raises: told below
                    errors.append(repr(exc))
            threads = [threading.Thread(target=read) for _ in range(3)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            truth = sum(rows for at, rows in born.values() if at > later - WINDOW)
            got = None if errors else day.total()
            if errors or got != truth:
                wrong.append((got, truth, errors[:1]))
    finally:
        sys.setswitchinterval(old_interval)
    print(f"{len(wrong)} of 10 days counted wrong: {wrong[:3]}")
    assert not wrong


def test_an_upload_read_with_the_kits_day_is_counted_once():
    """An upload's session counted in its kit's day while a stream of the kit is open
    (``Services.count_kit_samples``, after the upload's commit): a stream whose first
    message came between that commit and the count read the kit's day from the database
    (``day_of``) with the upload in it, and the count added the upload's rows again (the
    kit refused early, for as long as its socket stayed open). The upload's session holds
    its rows once, whichever came first."""
    from types import SimpleNamespace

    from armtrack.server.kit.daily_samples import KitDay
    from armtrack.server.services import Services

    created = datetime.now(UTC) - timedelta(minutes=5)
    read_with_it = SimpleNamespace(kit_samples={7: KitDay({41: (created, 1200)})})
    Services.count_kit_samples(read_with_it, 7, 41, created, 1200)
    read_before_it = SimpleNamespace(kit_samples={7: KitDay({})})
    Services.count_kit_samples(read_before_it, 7, 41, created, 1200)
    days = (read_with_it.kit_samples[7].total(), read_before_it.kit_samples[7].total())
    print(f"the kit's day after a 1200-row upload (read with it, before it): {days}")
    assert days == (1200, 1200)
