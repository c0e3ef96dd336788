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


def test_the_command_line_kit_stops_at_once_when_its_own_messages_are_refused(
        tmp_path_factory):
    """Close 4429 after ``ready`` means the server refused too many of the kit's own
    messages (``ARMTRACK_REFUSED_LIMIT`` in ``ARMTRACK_REFUSED_WINDOW_S``): trying again
    sends the same bad data, so the command exits 1 at once with the server's words,
    without "trying again". Here the bad data is marks past the most a session keeps
    (1000): each one after is refused."""
    server = ServerProcess(tmp_path_factory.mktemp("stream_refused"),
                           env={"ARMTRACK_REFUSED_LIMIT": "2"})
    server.create_user("alice")
    server.start()
    try:
        alice = server.client("alice")
        patient = alice.patient("Marks")
        token = alice.device(patient["id"])["token"]
        rows = "".join(f"{i / 50:.2f},forearm,0.0,9.81,0.0,0.0,0.0,0.0,,,\n"
                       for i in range(50 * 30))
        marks = "; ".join(f"{1 + i * 0.02:.2f} exercise:elbow_flexion" for i in range(1010))
        recording = tmp_path_factory.mktemp("marks") / "marks.csv"
        recording.write_text("# armtrack-recording: 1\n# side: right\n# height_m: 1.75\n"
                             f"# rate_hz: 50\n# marks: {marks}\n"
                             f"t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n{rows}")
        started = time.monotonic()
        done = subprocess.run(
            [sys.executable, "-m", "armtrack.server.cli", "stream", str(recording),
             "--speed", "0", "--quiet", "--url", server.ws_url, "--token", token],
            capture_output=True, text=True, timeout=170)
        took = time.monotonic() - started
        print(done.stderr, f"\nexited {done.returncode} after {took:.1f} s")
        assert done.returncode == 1, done.stderr
        assert "trying again" not in done.stderr.lower(), done.stderr
        last = done.stderr.strip().splitlines()[-1]
        assert "refused messages" in last and "4429" in last, last
        assert "marks" in last, last  # the last refused message, whole
        assert took < 30, took  # not the 60 s of --busy-retry, nor forever
    finally:
        server.stop()
