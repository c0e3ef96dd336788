"""A session without estimates says why and what to do. Found after restoring a backup
taken while a kit streamed: the restored session was 'interrupted', and its report, PDF and
exports answered "session 11 has no estimates yet (it is live or being processed)" — it was
neither, and nothing said to close it; an empty interrupted session, re-estimated, said
"sensors must be some of (...), got ()". A real server, ``armtrack stream`` killed mid-way
(the kit's power gone), a kit that says hello and nothing more."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import time

import websockets
from server_support import server_fixture

server = server_fixture("no-estimates", "alice")

EXPORTS = ("report", "report.pdf", "report.csv", "angles.csv")


def test_an_interrupted_session_says_to_close_it(server):
    api = server.client("alice")
    patient = api.patient("Cut Off")
    token = api.device(patient["id"], "kit")["token"]
    kit = subprocess.Popen(
        [sys.executable, "-m", "armtrack.server.cli", "stream", "--exercise", "elbow_flexion",
         "--url", server.ws_url, "--token", token, "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            sessions = api.http.get(f"/api/patients/{patient['id']}/sessions").json()
            if sessions and sessions[0]["samples"] > 600:
                break
            time.sleep(0.2)
    finally:
        kit.send_signal(signal.SIGKILL)
        kit.wait()
    session = sessions[0]["id"]
    deadline = time.monotonic() + 30
    while api.session(session)["status"] != "interrupted" and time.monotonic() < deadline:
        time.sleep(0.2)
    for path in EXPORTS:
        answer = api.http.get(f"/api/sessions/{session}/{path}")
        print(path, answer.status_code, answer.text[:300])
        assert answer.status_code == 409
        detail = answer.json()["detail"]
        assert "live or being processed" not in detail
        assert f"session {session} was interrupted" in detail and "close it" in detail


def test_a_session_without_samples_says_so(server):
    api = server.client("alice")
    patient = api.patient("Said Hello")
    token = api.device(patient["id"], "kit")["token"]

    async def hello_only():
        async with websockets.connect(f"{server.ws_url}?token={token}") as ws:
            await ws.send('{"type": "hello", "protocol": 1, "device": "kit", "sensors": '
                          '["upper_arm", "forearm"], "rate_hz": 50, "side": "right", '
                          '"nine_axis": false, "resume": null}')
            print(await ws.recv())
    asyncio.run(hello_only())
    session = api.http.get(f"/api/patients/{patient['id']}/sessions").json()[0]["id"]
    closed = api.http.post(f"/api/sessions/{session}/close")
    print("close:", closed.status_code, closed.text[:300])
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        answer = api.http.get(f"/api/sessions/{session}/report")
        if "being estimated" not in answer.text:
            break
        time.sleep(0.5)
    print(answer.status_code, answer.text)
    assert answer.status_code == 409
    detail = answer.json()["detail"]
    assert f"session {session} holds no samples" in detail, detail
    assert "sensors must be" not in detail
    # and IT's re-estimation says the same in its words
    done = server.armtrack("reprocess", str(session), timeout=180)
    print("reprocess:", done.returncode, done.stderr.strip())
    assert done.returncode == 2
    assert "holds no samples" in done.stderr and "sensors must be" not in done.stderr
