"""Security review (review7's finding 5): a therapist's close on one server instance while
the kit streams to another (README "Scaling out"; two ``armtrack serve`` processes on one
SQLite file here). ``mark_closed`` is one conditional UPDATE, so of closes at once exactly
one wins, but the close ends only the streams of its own instance
(``Services.end_session_streams``, ``Services.closing`` are per process). Before, the
kit's stream on the other instance went on, and what it sent after the close was stored
into the closed session and acked — after its estimation began, so the estimate left it
out, and the kit was never told its session ended (the 10 messages sent after the
close's 202 were all acked, ack 19, the stream still open). Now the other instance's
group writer reads the session with the stream's position in its commit (``writer``'s
"Fencing"): a closed session takes nothing more, unacked, and the stream ends 1000 as a
close on its own instance would end it."""

from __future__ import annotations

import asyncio
import contextlib
import json

import numpy as np
import pytest
from server_support import ServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    """Servers A and B: two processes, one data folder (one SQLite file)."""
    folder = tmp_path_factory.mktemp("two-instances")
    a, b = ServerProcess(folder), ServerProcess(folder)
    a.create_user("alice")
    a.start()
    b.start()
    yield a, b
    b.stop()
    a.stop()


def _samples(seq: int) -> str:
    t = (np.arange(100) + 100 * seq) / 50
    rows = np.column_stack([t, np.zeros(100), np.zeros(100), np.full(100, 9.81),
                            np.zeros((100, 3)), np.full((100, 3), np.nan)])
    return json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                       "rows": [[*r[:7], None, None, None] for r in rows.tolist()]})


def test_a_close_on_one_instance_ends_the_stream_on_another(two):
    a, b = two
    api = a.client("alice")
    patient = api.patient("Two servers")
    token = api.device(patient["id"])["token"]

    async def run():
        async with connect(f"{b.ws_url}?token={token}") as ws:
            await ws.send(json.dumps(HELLO))
            ready = json.loads(await ws.recv())
            assert ready["type"] == "ready", ready
            for seq in range(10):
                await ws.send(_samples(seq))
            while (message := json.loads(await ws.recv())) != {"type": "ack", "seq": 9}:
                assert message["type"] != "error", message
            close = await asyncio.to_thread(api.http.post,
                                            f"/api/sessions/{ready['session']}/close",
                                            params={"wait": "false"})
            assert close.status_code == 202, close.text
            acked, closed = 9, None
            try:
                for seq in range(10, 20):
                    await ws.send(_samples(seq))
                async with asyncio.timeout(5):
                    while True:
                        message = json.loads(await ws.recv())
                        if message["type"] == "ack":
                            acked = message["seq"]
            except ConnectionClosed as exc:
                closed = exc.rcvd.code if exc.rcvd else -1
            except TimeoutError:
                pass
            return ready["session"], acked, closed

    session_id, acked, closed = asyncio.run(run())
    stored = a.sql("SELECT COALESCE(SUM(n_rows), 0) FROM sample_blocks "
                   "WHERE session_id = :s", s=session_id)[0][0]
    print(f"after the close on A: last ack {acked}, close code on B {closed}, "
          f"samples stored {stored} (1000 before the close)")
    assert closed is not None, "the kit's stream on B stayed open after the close on A"
    assert acked == 9, f"messages sent after the close were acked up to {acked}"
    assert closed == 1000 and stored == 1000, (closed, stored)


def test_a_kit_revoked_on_one_instance_stops_streaming_to_another(two):
    # a revoke closed the kit's streams of its own instance only: on the other, the
    # revoked token went on streaming into the patient's record, acked, for good
    a, b = two
    api = a.client("alice")
    patient = api.patient("Revoked elsewhere")
    kit = api.device(patient["id"])

    async def run() -> tuple[int | None, float]:
        async with connect(f"{b.ws_url}?token={kit['token']}") as ws:
            await ws.send(json.dumps(HELLO))
            assert json.loads(await ws.recv())["type"] == "ready"
            revoked = await asyncio.to_thread(api.http.delete, f"/api/devices/{kit['id']}")
            assert revoked.status_code == 204, revoked.text
            start = asyncio.get_running_loop().time()
            try:  # B learns it at its next periodic check (ARMTRACK_ACCESS_CHECK_S, 5 s)
                async with asyncio.timeout(8):
                    for seq in range(10_000):
                        await ws.send(_samples(seq))
                        # read the acks, as a kit does: unread, 16 of them filled the
                        # client's queue and it stopped reading, the close behind them
                        with contextlib.suppress(TimeoutError):
                            async with asyncio.timeout(0.1):
                                while True:
                                    await ws.recv()
            except ConnectionClosed as exc:
                return (exc.rcvd.code if exc.rcvd else None,
                        asyncio.get_running_loop().time() - start)
            except TimeoutError:
                return None, asyncio.get_running_loop().time() - start
        return None, 0.0

    code, after_s = asyncio.run(run())
    print(f"\nthe revoked kit's stream on the other instance: close {code} after "
          f"{after_s:.1f} s")
    assert code == 4401, f"the revoked kit streamed on for {after_s:.1f} s"
