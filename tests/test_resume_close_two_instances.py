"""A kit's resume on one server instance while a therapist closes its session on another
(README "Scaling out"; two ``armtrack serve`` processes on one database: an SQLite file,
or PostgreSQL where the tests have one). The resume checks that the session is not
closed, then makes it live: a close committed on the other instance between the two was
overwritten, and the closed session went live again (its estimation already queued, the
kit told ``ready`` and streaming on into it). Now the resume makes the session live only
if it is still not closed (one conditional UPDATE), else the kit is told it is closed, as
when the close came first (closed-session/1: with ``next_seq``).

The race is made certain by a test hook in the servers' zygote: on the resuming instance
(``TEST_RESUME_GATE``, a folder), the resume stops after its closed check (at its kit
check, ``_same_kit``, called from ``_resume_session``), says so (``reached``) and waits
for the test's ``go``. A stream continuing the session (``session``, resume null) had
the same race (``_continue_session``), and is tested the same way."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import fresh_postgres_database
from server_support import Zygote, ZygoteServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

GATE_HOOK = """
import os as _os, sys as _sys, time as _time
from pathlib import Path as _Path
import armtrack.server.ingest.endpoint as _endpoint
_same_kit = _endpoint._same_kit
def _gated_same_kit(hello, session, what):
    gate = _os.environ.get("TEST_RESUME_GATE")
    if gate and _sys._getframe(1).f_code.co_name in ("_resume_session", "_continue_session"):
        (_Path(gate) / "reached").touch()
        deadline = _time.monotonic() + 60
        while not (_Path(gate) / "go").exists() and _time.monotonic() < deadline:
            _time.sleep(0.01)
    return _same_kit(hello, session, what)
_endpoint._same_kit = _gated_same_kit
"""

HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None,
         "extensions": ["closed-session/1"]}


def _samples(seq: int) -> str:
    t = (np.arange(100) + 100 * seq) / 50
    rows = np.column_stack([t, np.zeros(100), np.zeros(100), np.full(100, 9.81),
                            np.zeros((100, 3))])
    return json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                       "rows": [[*r, None, None, None] for r in rows.tolist()]})


@pytest.fixture(params=["sqlite", "postgres"])
def two(request, tmp_path):
    """Servers A and B on one database; B's resumes wait at the gate ``tmp_path/gate``."""
    env = ({} if request.param == "sqlite" else
           {"ARMTRACK_DATABASE_URL":
            fresh_postgres_database(request.getfixturevalue("postgres_url"))})
    gate = tmp_path / "gate"
    gate.mkdir()
    zygote = Zygote(GATE_HOOK)
    a = ZygoteServerProcess(tmp_path / "data", zygote, env)
    b = ZygoteServerProcess(tmp_path / "data", zygote, {**env, "TEST_RESUME_GATE": str(gate)})
    try:
        a.create_user("alice")
        a.start()
        b.start()
        yield a, b, gate
    finally:
        b.stop()
        a.stop()
        zygote.close()


def _wait_for(path: Path, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < deadline, f"{path.name} never came"
        time.sleep(0.01)


@pytest.mark.parametrize("how", ["resume", "continue"])
def test_a_close_elsewhere_during_a_resume_is_not_undone(two, how):
    a, b, gate = two
    api = a.client("alice")
    patient = api.patient("Resumed while closed")
    token = api.device(patient["id"])["token"]

    async def run():
        async with connect(f"{b.ws_url}?token={token}") as ws:  # the session, 10 messages
            await ws.send(json.dumps(HELLO))
            ready = json.loads(await ws.recv())
            assert ready["type"] == "ready", ready
            for seq in range(10):
                await ws.send(_samples(seq))
            while (message := json.loads(await ws.recv())) != {"type": "ack", "seq": 9}:
                assert message["type"] != "error", message
        # the connection is lost; the kit resumes (or continues the session in a new
        # stream) on B, which stops at the gate
        again = ({"resume": ready["stream"]} if how == "resume"
                 else {"session": ready["session"]})
        async with connect(f"{b.ws_url}?token={token}") as ws:
            await ws.send(json.dumps({**HELLO, **again}))
            await asyncio.to_thread(_wait_for, gate / "reached")
            close = await asyncio.to_thread(api.http.post,
                                            f"/api/sessions/{ready['session']}/close",
                                            params={"wait": "false"})
            assert close.status_code == 202, close.text
            (gate / "go").touch()
            answer = json.loads(await ws.recv())
            code = None
            try:
                async with asyncio.timeout(5):
                    while True:
                        await ws.recv()
            except ConnectionClosed as exc:
                code = exc.rcvd.code if exc.rcvd else -1
            except TimeoutError:
                pass
        return ready["session"], answer, code

    session_id, answer, code = asyncio.run(run())
    status = a.sql("SELECT status FROM sessions WHERE id = :s", s=session_id)[0][0]
    print(f"close on A during the {how} on B: the kit was told {answer}, closed {code}; "
          f"the session is {status!r}")
    assert status == "closed", f"the close on A was undone: the session is {status!r}"
    assert answer["type"] == "error" and "closed" in answer["reason"], answer
    if how == "resume":  # closed-session/1: the kit sends the rest from there anew
        assert answer.get("next_seq") == 10, answer
    assert code is not None
