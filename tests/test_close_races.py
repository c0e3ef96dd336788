"""Closes of one session at once (docs/extensions/close-without-wait.md): a double click,
two pages, two therapists' tabs, or a script. Each close that passes the "already
closed" check ends the session's streams, closes it and queues its estimation: several at
once queued several estimations of one session (each a full run of the estimator, and the
second rewrites the first's estimates). And a session erased while its close is under way
answered 500. Real server (SQLite file; PostgreSQL where the tests have one), a real
WebSocket kit."""

from __future__ import annotations

import asyncio
import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

CLOSES = 6


pytestmark = pytest.mark.both_databases  # mark_closed's one UPDATE on either


def stream_then(server, api, action):
    """A kit streams 20 s of one still sensor (acked), then ``action(session_id)`` runs
    while the kit stays connected: what it returned."""
    patient = api.patient("Closed at once")
    token = api.device(patient["id"])["token"]

    async def run():
        async with connect(f"{server.ws_url}?token={token}") as ws:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "device": "kit",
                                      "side": "right", "sensors": ["forearm"],
                                      "rate_hz": 50, "nine_axis": False, "resume": None}))
            ready = json.loads(await ws.recv())
            t = np.arange(1000) / 50
            rows = np.column_stack([t, np.zeros(1000), np.zeros(1000), np.full(1000, 9.81),
                                    np.zeros((1000, 3))]).tolist()
            for seq, start in enumerate(range(0, 1000, 100)):
                await ws.send(json.dumps({"type": "samples", "seq": seq, "sensor": "forearm",
                                          "rows": [[*r, None, None, None]
                                                   for r in rows[start:start + 100]]}))
            while (message := json.loads(await ws.recv())) != {"type": "ack", "seq": 9}:
                assert message["type"] != "error", message
            result = await asyncio.to_thread(action, ready["session"])
            with pytest.raises(ConnectionClosed):
                while True:
                    await ws.recv()
            return ready["session"], result
    return asyncio.run(run())


def test_closes_at_once_close_and_estimate_the_session_once(module_server):
    server = module_server
    api = server.client("alice")

    def close_at_once(session_id):
        with ThreadPoolExecutor(CLOSES) as pool:
            answers = list(pool.map(
                lambda _: api.http.post(f"/api/sessions/{session_id}/close?wait=false"),
                range(CLOSES)))
        return [(a.status_code, a.json().get("detail")) for a in answers]
    session_id, answers = stream_then(server, api, close_at_once)
    codes = sorted(code for code, _ in answers)
    print(f"\n{CLOSES} closes at once: {codes}; {sorted({d for _, d in answers if d})}")
    assert codes == [202] + [409] * (CLOSES - 1), answers
    estimated = api.wait_processed(session_id, timeout=300)
    assert estimated["status"] == "closed"


def test_a_session_erased_while_it_is_closed_is_not_a_server_error(module_server):
    server = module_server
    api = server.client("alice")

    def close_and_erase(session_id):
        with ThreadPoolExecutor(2) as pool:
            close = pool.submit(api.http.post, f"/api/sessions/{session_id}/close")
            erase = pool.submit(api.http.delete, f"/api/sessions/{session_id}")
            return close.result(), erase.result()
    session_id, (close, erase) = stream_then(server, api, close_and_erase)
    print(f"\nclose {close.status_code} {close.text[:120]!r}; erase {erase.status_code}")
    assert erase.status_code == 204
    assert close.status_code in (200, 404, 409), close.text
    assert api.http.get(f"/api/sessions/{session_id}").status_code == 404
