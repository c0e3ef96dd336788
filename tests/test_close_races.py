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
import time
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


def test_a_close_that_waited_through_a_reassignment_answers_404(module_server):
    """A close waits for the session's estimation (seconds, minutes behind others); an
    admin who gives the patient to another therapist meanwhile takes the session from the
    closing therapist: the close's answer (the estimated session: calibration, warnings,
    metadata) is then 404, as every other route of the session is to them; before, it
    was the session, read after the reassignment."""
    from server_support import PASSWORD
    from test_upload_beside_streams import big_recording

    server = module_server
    api, bob = server.client("alice"), server.client("bob")
    done = server.armtrack("create-user", "root7", "--admin", "--password", PASSWORD)
    assert done.returncode == 0, done.stderr
    root = server.client("root7")
    bob_id = next(t["id"] for t in root.http.get("/api/admin/therapists").json()
                  if t["username"] == "bob")
    # another patient's long recording keeps the estimation busy while the close waits
    other = api.patient("Long upload")
    busy = api.http.post("/api/recordings", timeout=300,
                         data={"patient_id": str(other["id"]), "wait": "false"},
                         files={"file": ("long.csv", big_recording(minutes=5))})
    assert busy.status_code == 202, busy.text

    def close_while_reassigned(session_id):
        patient_id = api.session(session_id)["patient_id"]
        with ThreadPoolExecutor(1) as pool:
            close = pool.submit(api.http.post, f"/api/sessions/{session_id}/close",
                                timeout=600)
            deadline = time.monotonic() + 60
            while api.session(session_id)["status"] != "closed":
                assert time.monotonic() < deadline and not close.done(), "not closed"
                time.sleep(0.02)
            moved = root.http.post(f"/api/admin/patients/{patient_id}/reassign",
                                   json={"therapist_id": bob_id})
            assert moved.status_code == 200, moved.text
            estimating = not close.done()
            return close.result(), estimating
    session_id, (close, estimating) = stream_then(server, api, close_while_reassigned)
    print(f"\nclose after the reassignment: {close.status_code} {close.text[:100]!r}")
    assert estimating, "the close answered before the reassignment: no race tested"
    assert close.status_code == 404, close.text
    assert close.json() == {"detail": f"no session {session_id}"}
    assert bob.wait_processed(session_id, timeout=600)["status"] == "closed"
