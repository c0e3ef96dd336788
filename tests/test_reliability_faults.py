"""Faults while kits stream, against a real server (forked from a :class:`Zygote` so that
it restarts in about a second): SIGKILL at random moments in 50 streaming runs; the disk
full (a small tmpfs filled up) and the database locked (an exclusive lock held by another
connection); a sensor that stalls, one that floods, one that reconnects every second; a
clock that jumps forward (a gap in the report's data quality) or back (refused; the kit
starts a new stream in the same session). After each: what is stored equals what was
sent, bit for bit, once; nothing acked is lost; every session ends closed or resumable."""

from __future__ import annotations

import asyncio
import contextlib
import json
import random
import sqlite3
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from armtrack.estimator.recording import Recording, SensorStream, parse_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from armtrack.server.emulator import KitEmulator
from server_support import Zygote, ZygoteServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

#: A test hook run in the zygote: ``TEST_SQLITE_BUSY_MS`` sets SQLite's busy timeout of
#: the server's engine (30 s in production), so that a held lock fails commits quickly.
BUSY_HOOK = """
import os as _os
import armtrack.server.services as _services
from sqlalchemy import event as _event
_make_engine = _services.make_engine
def _with_busy_timeout(url):
    engine = _make_engine(url)
    busy = _os.environ.get("TEST_SQLITE_BUSY_MS")
    if busy and engine.dialect.name == "sqlite":
        @_event.listens_for(engine, "connect")
        def _busy(dbapi_connection, _record):
            dbapi_connection.execute(f"PRAGMA busy_timeout={int(busy)}")
    return engine
_services.make_engine = _with_busy_timeout
"""


@pytest.fixture(scope="module")
def zygote():
    z = Zygote(BUSY_HOOK)
    yield z
    z.close()


@pytest.fixture(scope="module")
def srv(zygote, tmp_path_factory):
    process = ZygoteServerProcess(tmp_path_factory.mktemp("faults") / "server", zygote)
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


@pytest.fixture(scope="module")
def api(srv):
    return srv.client("alice")


def run(coroutine, timeout: float = 120):
    async def bounded():
        async with asyncio.timeout(timeout):
            return await coroutine
    return asyncio.run(bounded())


def new_device(api, name: str) -> tuple[int, str]:
    patient = api.patient(name)
    return patient["id"], api.device(patient["id"])["token"]


def recording(repetitions: int = 1, rate_hz: float = 50, seed: int = 3) -> Recording:
    return simulate(SimulationConfig(repetitions=repetitions, rate_hz=rate_hz,
                                     seed=seed)).recording


def export(api, session_id: int) -> Recording:
    answer = api.http.get(f"/api/sessions/{session_id}/recording.csv")
    assert answer.status_code == 200, answer.text
    return parse_recording(answer.content)


def assert_stored_exactly(api, session_id: int, sent: Recording) -> None:
    """The session holds every sample of ``sent``, once, bit for bit, and its marks."""
    stored = export(api, session_id)
    assert set(stored.sensors) == set(sent.sensors)
    for name, s in sent.sensors.items():
        got = stored.sensors[name]
        for column in ("t", "acc", "gyr", "mag"):
            a, b = getattr(got, column), getattr(s, column)
            assert a.shape == b.shape, (name, column, a.shape, b.shape)
            assert np.array_equal(a.view(np.int64), b.view(np.int64)), (name, column)
    assert stored.calibration == sent.calibration
    assert api.session(session_id)["samples"] == sum(len(s.t) for s in sent.sensors.values())


def sessions_of(api, patient_id: int) -> list[dict]:
    answer = api.http.get(f"/api/patients/{patient_id}/sessions", params={"limit": 200})
    assert answer.status_code == 200, answer.text
    return answer.json()


def settled_sessions(api, patient_id: int, timeout_s: float = 15.0) -> list[dict]:
    """The patient's sessions once none is live: the server acks a kit's ``bye`` and then
    closes its session, so a kit that has finished may look a moment early (seen once on
    a loaded machine); after ``timeout_s`` the sessions as they are."""
    deadline = time.monotonic() + timeout_s
    while True:
        sessions = sessions_of(api, patient_id)
        if all(s["status"] != "live" for s in sessions) or time.monotonic() > deadline:
            return sessions
        time.sleep(0.1)


# -- SIGKILL at random moments ---------------------------------------------------------------

def test_sigkill_at_random_moments_in_50_streaming_runs_loses_nothing(srv, api):
    """50 runs, each: a kit streams a 17 s recording (3 sensors × 50 Hz) 25× faster than
    real time, 5 to 50 rows a message; the server is SIGKILLed at a random moment (before
    the hello, mid-stream, during the bye) and started again; the kit resumes (or starts
    again when it never got ``ready``). Then: stored = sent exactly (no sample lost, none
    twice), the emulator saw no acked message asked for again, and every session of the
    patient is closed or resumable (interrupted), only the kit's holding data."""
    rng = random.Random(8)
    base = recording()
    kills = {"before ready": 0, "mid-stream": 0, "after all sent": 0}
    resumed = 0
    for i in range(50):
        patient_id, token = new_device(api, f"Killed {i}")
        kit = KitEmulator(base, srv.ws_url, token, speed=25,
                          rows_per_message=rng.choice([5, 10, 20, 50]), max_retries=200,
                          backoff_s=(0.05, 0.3), ack_timeout_s=10, open_timeout_s=5)
        # one run in eight is killed within 30 ms of the kit's start (before or at its hello)
        delay = rng.uniform(0.0, 0.03) if i % 8 == 0 else rng.uniform(0.0, 1.0)

        async def one_run(kit: KitEmulator = kit, delay: float = delay) -> None:
            task = asyncio.create_task(kit.run())
            await asyncio.sleep(delay)
            await asyncio.to_thread(srv.kill)
            if kit.stats.stream is None:
                kills["before ready"] += 1
            elif kit.outbox.next_seq < len(kit.plan):
                kills["mid-stream"] += 1
            else:
                kills["after all sent"] += 1
            await asyncio.to_thread(srv.start)
            await task

        run(one_run(), timeout=60)
        stats = kit.stats
        assert stats.acked == stats.total and stats.refused == 0, (i, stats.errors)
        resumed += stats.reconnects > 0
        assert_stored_exactly(api, stats.session, base)
        for session in settled_sessions(api, patient_id):
            assert session["status"] in ("closed", "interrupted"), (i, session)
            if session["id"] != stats.session:
                assert session["samples"] == 0, (i, session)
    print(f"50 SIGKILLs: {kills}; {resumed} kits resumed their stream")
    assert resumed >= 20 and kills["mid-stream"] >= 20, (resumed, kills)


# -- the disk full, the database locked ------------------------------------------------------

def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True)
    return done.returncode == 0


def _fill(path: Path) -> Path:
    """Fill the file system of ``path`` to the last byte; returns the filler file."""
    filler = path / "filler"
    chunk = b"\0" * (1 << 16)
    with open(filler, "wb", buffering=0) as file:  # unbuffered: nothing left to flush
        for size in (len(chunk), 4096, 1):
            with contextlib.suppress(OSError):
                while file.write(chunk[:size]):
                    pass
    return filler


async def _stream_through_a_fault(kit: KitEmulator, start_fault, end_fault,
                                  fault_s: float) -> dict[str, Any]:
    """Run ``kit``; after its first acks, cause a fault for ``fault_s`` seconds. Returns
    what the kit saw during the fault."""
    task = asyncio.create_task(kit.run())
    while kit.stats.acked < 20:
        await asyncio.sleep(0.02)
        assert not task.done(), task.result()
    errors_before = len(kit.stats.errors)
    await asyncio.to_thread(start_fault)
    await asyncio.sleep(0.3)  # a commit in flight may still end
    acked_during = kit.stats.acked
    pending_during = len(kit.outbox.pending)
    await asyncio.sleep(fault_s)
    seen = {"errors": kit.stats.errors[errors_before:], "acked_moved":
            kit.stats.acked - acked_during, "pending": pending_during,
            "pending_end": len(kit.outbox.pending)}
    await asyncio.to_thread(end_fault)
    await task
    return seen


def test_a_full_disk_gives_errors_keeps_the_unacked_data_and_recovers(zygote, tmp_path):
    """The data folder on a 24 MB tmpfs; while a kit streams, the disk is filled to the
    last byte for 3 s: commits fail ("database or disk is full"), the kit gets errors
    (``seq`` null: nothing refused) and keeps its unacked messages, no ack moves on;
    when the filler is deleted, everything is stored once and the session closes."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "24m"):
        pytest.skip("cannot mount a tmpfs here (needs root, as in CI)")
    server = ZygoteServerProcess(disk / "server", zygote)
    server.log = tmp_path / "server.log"  # the log must not need the full disk
    try:
        server.create_user("alice")
        server.start()
        api = server.client("alice")
        _, token = new_device(api, "Disk full")
        sent = recording(repetitions=2, rate_hz=100)
        kit = KitEmulator(sent, server.ws_url, token, speed=4, ack_timeout_s=30)
        filler: list[Path] = []
        seen = run(_stream_through_a_fault(kit, lambda: filler.append(_fill(disk)),
                                           lambda: filler[0].unlink(), 3.0))
        assert seen["acked_moved"] == 0 and seen["pending_end"] > seen["pending"] > 0, seen
        storage = [e for e in seen["errors"] if "storage failed" in e["reason"]]
        assert storage and all(e["seq"] is None for e in storage), seen["errors"]
        assert kit.stats.refused == 0 and kit.stats.acked == kit.stats.total
        assert_stored_exactly(api, kit.stats.session, sent)
        assert api.settled(kit.stats.session)["status"] == "closed"
        assert "database or disk is full" in server.log.read_text()
    finally:
        server.stop()
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_a_locked_database_gives_errors_keeps_the_unacked_data_and_recovers(zygote, tmp_path):
    """Another connection holds an exclusive lock on the SQLite file for 3 s while a kit
    streams (the server's busy timeout set to 0.3 s by the test hook; 30 s in
    production): commits fail ("database is locked"), the kit gets errors and keeps its
    unacked messages; once the lock goes, everything is stored once. A second kit that
    loses its connection during the lock is let go cleanly (its session cannot be marked
    interrupted then) and resumes afterwards."""
    server = ZygoteServerProcess(tmp_path / "server", zygote,
                                 env={"TEST_SQLITE_BUSY_MS": "300"})
    lock = threading.Event()
    locked = threading.Event()

    def hold() -> None:
        db = sqlite3.connect(server.data_dir / "armtrack.db", timeout=30,
                             isolation_level=None)
        db.execute("BEGIN EXCLUSIVE")
        locked.set()
        lock.wait(30)
        db.execute("ROLLBACK")
        db.close()

    holder = threading.Thread(target=hold, daemon=True)
    try:
        server.create_user("alice")
        server.start()
        api = server.client("alice")
        _, token = new_device(api, "Locked")
        sent = recording(repetitions=2, rate_hz=100)
        kit = KitEmulator(sent, server.ws_url, token, speed=4, ack_timeout_s=30)

        _, other_token = new_device(api, "Leaves while locked")
        hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
                 "sensors": ["forearm"], "rate_hz": 100, "nine_axis": True, "resume": None}
        row = [0.0, 0.1, 0.2, 9.8, 0.01, 0.02, 0.03, 20.0, 5.0, -30.0]

        async def scenario():
            # a second kit, one message stored, loses its connection during the lock: the
            # server cannot mark its session interrupted, and must let the stream go
            other = await _bare(server, other_token)
            await other.send(json.dumps(hello))
            ready = await _reply(other)
            await other.send(json.dumps({"type": "samples", "seq": 0, "sensor": "forearm",
                                         "rows": [row]}))
            assert (await _reply(other, skip_acks=False)) == {"type": "ack", "seq": 0}

            def start() -> None:
                holder.start()
                assert locked.wait(10)
                other.transport.abort()

            seen = await _stream_through_a_fault(kit, start, lock.set, 3.0)
            again = await _bare(server, other_token)
            await again.send(json.dumps({**hello, "resume": ready["stream"]}))
            resumed = await _reply(again)
            assert resumed == {"type": "ready", "stream": ready["stream"],
                               "session": ready["session"], "next_seq": 1}, resumed
            await again.send(json.dumps({"type": "bye"}))
            with contextlib.suppress(ConnectionClosed):
                while True:
                    await _reply(again)
            return seen, ready["session"]

        seen, other_session = run(scenario())
        holder.join(10)
        assert api.session(other_session)["status"] == "closed"
        assert api.session(other_session)["samples"] == 1
        log = server.log.read_text()
        assert "Traceback" not in log and "Exception in ASGI" not in log, log[-3000:]
        assert seen["acked_moved"] == 0 and seen["pending_end"] > seen["pending"] > 0, seen
        storage = [e for e in seen["errors"] if "storage failed" in e["reason"]]
        assert storage and all(e["seq"] is None for e in storage), seen["errors"]
        assert kit.stats.refused == 0 and kit.stats.acked == kit.stats.total
        assert_stored_exactly(api, kit.stats.session, sent)
        assert api.settled(kit.stats.session)["status"] == "closed"
        assert "database is locked" in server.log.read_text()
    finally:
        lock.set()
        server.stop()


# -- sensors that stall, flood, reconnect every second ---------------------------------------

class StallingKit(KitEmulator):
    """Sends nothing for ``stall_s`` seconds once message ``at`` is due (the sensor hangs),
    then goes on: every later message is that much late."""

    def __init__(self, *args, at: int, stall_s: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.at, self.stall_s = at, stall_s

    def due(self, seq: int) -> float:
        return super().due(seq) + (self.stall_s if seq >= self.at else 0.0)


def test_sensors_that_stall_flood_or_reconnect_every_second_lose_nothing(srv, api):
    """At once on one server: a kit that stalls 4 s mid-stream (longer than the ack
    period: the connection stays, no reconnect); one that floods (3 repetitions at
    100 Hz sent as fast as it can, 50 rows a message); one that loses its connection
    about every second (no close frame) and resumes; and a steady kit in real time. All
    four store exactly what they sent, and the steady kit's acks keep coming (p99 < 1 s)."""
    short = recording(seed=4)
    long = recording(repetitions=3, rate_hz=100, seed=5)
    tokens = [new_device(api, name)[1] for name in ("Stall", "Flood", "Flaky", "Steady")]
    stall = StallingKit(short, srv.ws_url, tokens[0], speed=4, at=60, stall_s=4.0)
    flood = KitEmulator(long, srv.ws_url, tokens[1], speed=0, rows_per_message=50)
    flaky_plan_speed = 3.0  # ~1 s of the recording's 3 sensors × 50 Hz at 10 rows: 15 msgs
    per_second = int(3 * 50 / 10 * flaky_plan_speed)
    flaky = KitEmulator(short, srv.ws_url, tokens[2], speed=flaky_plan_speed,
                        drop_after_seqs=range(per_second, 10_000, per_second),
                        max_retries=50, backoff_s=(0.05, 0.2))
    steady = KitEmulator(short, srv.ws_url, tokens[3], speed=2)

    async def all_four():
        return await asyncio.gather(*(k.run() for k in (stall, flood, flaky, steady)))

    run(all_four(), timeout=90)
    for kit, sent in ((stall, short), (flood, long), (flaky, short), (steady, short)):
        stats = kit.stats
        assert stats.acked == stats.total and stats.refused == 0 and not stats.errors, (
            kit, stats.errors)
        assert_stored_exactly(api, stats.session, sent)
        assert api.settled(stats.session)["status"] == "closed"
    assert stall.stats.reconnects == 0 and steady.stats.reconnects == 0
    assert flaky.stats.drops >= 4 and flaky.stats.reconnects == flaky.stats.drops
    assert steady.stats.latency_percentiles((99,))[99] < 1.0


# -- the kit's clock jumps ---------------------------------------------------------------------

def shifted(sent: Recording, after: float, by: float) -> Recording:
    """``sent`` with every time stamp (and pose, mark) after ``after`` moved by ``by`` s."""
    def move(t: float) -> float:
        return t + by if t > after else t

    sensors = {name: SensorStream(np.where(s.t > after, s.t + by, s.t), s.acc, s.gyr, s.mag)
               for name, s in sent.sensors.items()}
    calibration = tuple(type(p)(p.name, move(p.start), move(p.end)) for p in sent.calibration)
    marks = tuple(type(m)(move(m.t), m.label) for m in sent.marks)
    return Recording(side=sent.side, sensors=sensors, height_m=sent.height_m,
                     calibration=calibration, marks=marks, rate_hz=sent.rate_hz)


def test_a_clock_jumping_forward_is_a_gap_in_the_reports_data_quality(srv, api):
    """The kit's clock jumps 6 s forward after 10 s: every sample is stored as sent, and
    the session report's data quality names the gap (per sensor, with its start and end)
    and warns about it."""
    sent = shifted(recording(seed=6), after=10.0, by=6.0)
    _, token = new_device(api, "Clock forward")
    kit = KitEmulator(sent, srv.ws_url, token, speed=0)
    stats = run(kit.run())
    assert stats.acked == stats.total and not stats.errors
    assert_stored_exactly(api, stats.session, sent)
    api.wait_processed(stats.session)
    answer = api.http.get(f"/api/sessions/{stats.session}/report")
    assert answer.status_code == 200, answer.text
    quality = answer.json()["quality"]
    for sensor in quality["sensors"]:
        assert len(sensor["gaps"]) == 1, sensor
        gap = sensor["gaps"][0]
        assert gap["start_s"] == pytest.approx(10.0, abs=0.03)
        assert gap["end_s"] == pytest.approx(16.0, abs=0.03)
    assert any("gap" in w and "clock" in w for w in quality["warnings"]), quality["warnings"]


async def _bare(srv, token: str) -> Any:
    return await connect(srv.ws_url, additional_headers={"Authorization": f"Bearer {token}"},
                         open_timeout=10, max_size=None)


async def _reply(ws, timeout: float = 10.0, skip_acks: bool = True) -> dict[str, Any]:
    while True:
        message = json.loads(await asyncio.wait_for(ws.recv(), timeout))
        if not (skip_acks and message["type"] == "ack"):
            return message


def _messages(sent: Recording, rows: int = 10, t_shift: float = 0.0) -> list[dict]:
    """``samples`` messages of ``sent`` in time order (``t_shift`` added to ``t``)."""
    out = []
    names = list(sent.sensors)
    n = len(sent.sensors[names[0]].t)
    for start in range(0, n, rows):
        for name in names:
            s = sent.sensors[name]
            block = np.column_stack([s.t[start:start + rows] + t_shift,
                                     s.acc[start:start + rows], s.gyr[start:start + rows],
                                     s.mag[start:start + rows]])
            out.append({"type": "samples", "sensor": name, "rows": block.tolist()})
    return out


def test_a_clock_jumping_back_is_refused_and_a_new_stream_continues_the_session(srv, api):
    """After 8 s the kit's clock restarts at 0: its message is refused naming its seq
    ("t goes backwards … starts a new stream in this session"); the old stream cannot be
    resumed into it; the kit says hello with ``resume`` null and ``session`` = its
    session, gets a new stream with ``t_offset`` (one sample period after the session's
    last time), sends the rest on its restarted clock, and says bye. The session holds
    every sample once, its times going on without a gap (``t + t_offset``), and closes."""
    whole = recording(seed=7)
    split = 8.0
    first = Recording(side=whole.side, sensors={
        n: SensorStream(s.t[s.t < split], s.acc[s.t < split], s.gyr[s.t < split],
                        s.mag[s.t < split]) for n, s in whole.sensors.items()},
        height_m=whole.height_m, rate_hz=whole.rate_hz)
    rest = {n: SensorStream(s.t[s.t >= split], s.acc[s.t >= split], s.gyr[s.t >= split],
                            s.mag[s.t >= split]) for n, s in whole.sensors.items()}
    second = Recording(side=whole.side, sensors=rest, height_m=whole.height_m,
                       rate_hz=whole.rate_hz)
    restart = float(next(iter(rest.values())).t[0])  # the new clock's 0
    _, token = new_device(api, "Clock back")
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": whole.side,
             "sensors": list(whole.sensors), "rate_hz": 50, "nine_axis": True,
             "resume": None}

    async def stream():
        ws = await _bare(srv, token)
        await ws.send(json.dumps(hello))
        ready = await _reply(ws)
        assert ready["type"] == "ready" and "t_offset" not in ready
        messages = _messages(first)
        for seq, m in enumerate(messages):
            await ws.send(json.dumps({**m, "seq": seq}))
        back = {**_messages(second, t_shift=-restart)[0], "seq": len(messages)}
        await ws.send(json.dumps(back))
        error = await _reply(ws)
        assert error["type"] == "error" and error["seq"] == len(messages), error
        for word in ("backwards", "new stream", "session"):
            assert word in error["reason"], error
        await ws.close()
        # the old stream is not resumed into a session that a new stream goes on with
        ws = await _bare(srv, token)
        await ws.send(json.dumps({**hello, "session": ready["session"]}))
        again = await _reply(ws)
        assert again["type"] == "ready" and again["session"] == ready["session"], again
        assert again["stream"] != ready["stream"] and again["next_seq"] == 0
        last = max(float(s.t[-1]) for s in first.sensors.values())
        assert again["t_offset"] == last + 1 / 50
        for seq, m in enumerate(_messages(second, t_shift=-restart)):
            await ws.send(json.dumps({**m, "seq": seq}))
        old = await _bare(srv, token)  # the old stream's clock is behind: no resume
        await old.send(json.dumps({**hello, "resume": ready["stream"]}))
        refused = await _reply(old)
        assert refused["type"] == "error" and "newer stream" in refused["reason"], refused
        await ws.send(json.dumps({"type": "bye"}))
        with contextlib.suppress(ConnectionClosed):
            while True:
                await _reply(ws)
        return ready["session"], again["t_offset"]

    session_id, offset = run(stream())
    stored = export(api, session_id)
    for name, s in whole.sensors.items():
        got = stored.sensors[name]
        expect_t = np.concatenate([first.sensors[name].t,
                                   (rest[name].t - restart) + offset])
        assert np.array_equal(got.t.view(np.int64), expect_t.view(np.int64)), name
        assert np.array_equal(got.acc, s.acc) and np.array_equal(got.mag, s.mag)
        assert (np.diff(got.t) > 0).all()
    session = api.session(session_id)
    assert session["status"] == "closed"
    assert session["samples"] == sum(len(s.t) for s in whole.sensors.values())


def test_a_new_stream_may_not_continue_a_session_that_is_not_its_own_or_closed(srv, api):
    """``session`` of another patient, of nobody, or closed: hello refused (4400) with a
    reason; ``resume`` and ``session`` together too."""
    _, token = new_device(api, "Continuer")
    _, other_token = new_device(api, "Someone else")
    hello = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
             "sensors": ["forearm"], "rate_hz": 50, "nine_axis": True, "resume": None}

    async def refused(tok: str, **changes) -> str:
        ws = await _bare(srv, tok)
        await ws.send(json.dumps({**hello, **changes}))
        reply = await _reply(ws)
        with contextlib.suppress(ConnectionClosed):
            await ws.recv()
        assert reply["type"] == "error" and ws.close_code == 4400, (reply, ws.close_code)
        return reply["reason"]

    async def scenario():
        ws = await _bare(srv, other_token)
        await ws.send(json.dumps(hello))
        theirs = (await _reply(ws))["session"]
        await ws.send(json.dumps({"type": "bye"}))
        with contextlib.suppress(ConnectionClosed):
            while True:
                await _reply(ws)
        assert "no session" in await refused(token, session=theirs)
        assert "no session" in await refused(token, session=10**9)
        assert "closed" in await refused(other_token, session=theirs)
        assert "not both" in await refused(token, session=theirs, resume="abc")
        assert "session must be" in await refused(token, session="1")

    run(scenario())
