"""``armtrack stream`` (the command-line kit) and a server that refuses the kit for now
(close 4429: too many new sessions this hour, too many streams open). It gave up at the
first refusal ("the server refused too many messages") although waiting is all it takes;
the phone kit tries again (0.5 s doubling to 5 s). The command now tries again the same
way, saying why and for how long, and gives up after ``--busy-retry`` seconds (default
60) with what to do. Real server, real database file, the real command in a process."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from datetime import UTC, datetime, timedelta

import pytest
from server_support import ServerProcess

SETTING = "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR"


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("stream_busy"), env={SETTING: "1"})
    server.create_user("alice")
    server.start()
    yield server
    server.stop()


def stream(srv, token: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise", "still",
         "--rate", "50", "--speed", "0", "--quiet", "--url", srv.ws_url, "--token", token,
         *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def lines_of(stream_: subprocess.Popen) -> tuple[list[str], threading.Event]:
    """Its standard error's lines as they come; the event is set at the first line."""
    lines: list[str] = []
    first = threading.Event()

    def read():
        for line in stream_.stderr:
            lines.append(line.rstrip("\n"))
            first.set()

    threading.Thread(target=read, daemon=True).start()
    return lines, first


def test_the_command_line_kit_waits_while_the_server_refuses_it_for_now(srv):
    alice = srv.client("alice")
    patient = alice.patient("Busy")
    token = alice.device(patient["id"])["token"]
    stored = lambda: srv.sql("SELECT id, samples FROM sessions WHERE patient_id = :p "  # noqa: E731
                             "ORDER BY id", p=patient["id"])

    first = stream(srv, token)
    out, err = first.communicate(timeout=180)
    assert first.returncode == 0, err
    assert len(stored()) == 1

    # the kit's one session this hour is spent: the next waits, saying so
    second = stream(srv, token)  # tries for 60 s by default
    lines, spoke = lines_of(second)
    assert spoke.wait(120), "the command said nothing while refused"
    time.sleep(2)  # a few tries
    print("\n".join(lines))
    assert second.poll() is None, f"gave up at once: {lines}"
    assert any(SETTING in line and "trying again in" in line.lower() for line in lines), lines
    assert len(stored()) == 1  # nothing stored while refused
    hour_ago = (datetime.now(UTC) - timedelta(hours=1, minutes=1)).strftime(
        "%Y-%m-%d %H:%M:%S.%f")
    srv.sql("UPDATE sessions SET started_at = :t, created_at = :t WHERE patient_id = :p",
            t=hour_ago, p=patient["id"])
    out, _ = second.communicate(timeout=120)
    print(out)
    assert second.returncode == 0, lines
    rows = stored()
    assert len(rows) == 2 and rows[1][1] == rows[0][1] > 0, rows  # all of it, once

    # a bounded wait: given up after --busy-retry, saying what to do
    started = time.monotonic()
    third = stream(srv, token, "--busy-retry", "3")
    out, err = third.communicate(timeout=120)
    took = time.monotonic() - started
    print(err, f"\ngave up after {took:.1f} s")
    assert third.returncode == 1
    last = err.strip().splitlines()[-1]
    assert SETTING in last and "--busy-retry" in last, last
    assert err.lower().count("trying again in") >= 2, err
    assert len(stored()) == 2
