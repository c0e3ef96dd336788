"""Issue 17, what a kit's token can reach on ``/ws/ingest`` and ``POST /api/recordings``,
on a real server: another patient's live stream is never touched by a ``hello`` naming
its session or stream (item 4); a kit revoked since its socket connected starts no
stream; an upload is stored only while the right it was let in with still holds (att19).

That last: a recording upload is checked (the uploader's token, their patient) when its
body has arrived, then read and parsed (seconds for a large file, up to two minutes for an
APDM ``.h5``), then stored. A right that went in between — the patient reassigned to
another therapist or erased, the account disabled, the sign-in ended, the kit revoked —
was not looked at again: the session was stored in the patient's record all the same,
written by someone who no longer held it. The window is held open without guessing at
timing: the test takes SQLite's write lock, so each upload waits at its first write, past
its checks and inside its therapist's read turn (``imports.therapist_turn``, two at
once); a third request of the therapist answered 429 says both are there. The change is
then made in the lock's transaction, as another server instance on the same database
makes it, and the lock given back. (It shares this module's server: a file of its own
cost a server's start and, with the uploads' processing under way, a 15-s stop.)"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import sqlite3
import time

import httpx
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}


async def kit(server, token: str, **hello):
    ws = await connect(server.ws_url, additional_headers={"Authorization": f"Bearer {token}"})
    await ws.send(json.dumps({**HELLO, **hello}))
    return ws, json.loads(await asyncio.wait_for(ws.recv(), 10))


async def refused_hello(server, token: str, **hello) -> tuple[dict, int | None]:
    """A hello that must be refused: its error and the close code."""
    ws, answer = await kit(server, token, **hello)
    try:
        await asyncio.wait_for(ws.recv(), 5)
    except ConnectionClosed as exc:
        return answer, exc.rcvd.code if exc.rcvd else None
    return answer, None


def test_a_hello_naming_another_patients_session_or_stream_touches_nothing(module_server):
    alice, bob = module_server.client("alice"), module_server.client("bob")
    victim = alice.device(alice.patient("Victim")["id"])["token"]
    attacker = bob.device(bob.patient("Attacker")["id"])["token"]

    async def scenario():
        ws, ready = await kit(module_server, victim)
        assert ready["type"] == "ready", ready
        answers = [await refused_hello(module_server, attacker, session=ready["session"]),
                   await refused_hello(module_server, attacker, resume=ready["stream"])]
        # the victim's stream is untouched: it goes on and is acked
        row = [0.0, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, None, None, None]
        await ws.send(json.dumps({"type": "samples", "seq": 0, "sensor": "forearm",
                                  "rows": [row]}))
        try:
            async with asyncio.timeout(10):
                while (message := json.loads(await ws.recv()))["type"] != "ack":
                    pass
        except ConnectionClosed as exc:
            pytest.fail(f"the victim's stream was closed: {exc.rcvd}")
        await ws.send(json.dumps({"type": "bye"}))
        await ws.close()
        return answers, message

    answers, ack = asyncio.run(scenario())
    assert ack == {"type": "ack", "seq": 0}
    for (error, code), words in zip(answers, ("no session", "no stream"), strict=True):
        assert error["type"] == "error" and words in error["reason"], error
        assert code == 4400, code


def test_a_refusal_echoing_wide_characters_still_closes_with_its_code(module_server):
    """A refusal's close reason is cut to fit a close frame (123 bytes of UTF-8): a hello
    whose bad value is echoed in wide characters (``side``, an unknown sensor's name) was
    cut to 120 characters, up to 360 bytes, the close failed and the kit saw 1006 (a
    dropped network, to be retried) instead of 4400 (a hello the server cannot use)."""
    alice = module_server.client("alice")
    token = alice.device(alice.patient("Wide refusals")["id"])["token"]

    async def scenario():
        return [await refused_hello(module_server, token, side="€" * 100),
                await refused_hello(module_server, token, sensors=["épaule_" + "é" * 80])]

    for (error, code), field in zip(asyncio.run(scenario()), ("side", "unknown sensor"),
                                    strict=True):
        print(code, error["reason"][:60])
        assert error["type"] == "error" and field in error["reason"], error
        assert code == 4400, (code, error["reason"][:60])


@pytest.mark.parametrize("change", ["revoked", "erased"])
def test_a_socket_opened_before_the_kit_was_revoked_cannot_start_a_stream(module_server,
                                                                          change):
    """A kit's socket counts from its connection (one of the token's four), but it was
    known to the revoke only once its hello had made a stream: a socket opened before the
    kit was revoked, its hello sent after, started a new session in the patient's record
    and streamed into it, acked (until the periodic check, ≤ 5 s later). A stolen phone's
    token, its sockets opened ahead and kept idle, wrote on after the therapist revoked it.
    With the patient erased, the hello failed on an assertion (att19)."""
    alice = module_server.client("alice")
    patient = alice.patient(f"Kit {change} while idle")
    device = alice.device(patient["id"])

    async def scenario():
        ws = await connect(module_server.ws_url,
                           additional_headers={"Authorization": f"Bearer {device['token']}"})
        path = f"/api/devices/{device['id']}" if change == "revoked" \
            else f"/api/patients/{patient['id']}"
        answer = await asyncio.to_thread(alice.http.delete, path)
        assert answer.status_code == 204, answer.text
        await ws.send(json.dumps(HELLO))
        messages = []
        try:
            async with asyncio.timeout(10):
                while True:
                    messages.append(json.loads(await ws.recv()))
                    if messages[-1]["type"] == "ready":  # write, as the stolen token would
                        await ws.send(json.dumps({
                            "type": "samples", "seq": 0, "sensor": "forearm",
                            "rows": [[0.0, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, None, None, None]]}))
        except ConnectionClosed as exc:
            return messages, exc.rcvd.code if exc.rcvd else None
        await ws.close()
        return messages, None

    messages, code = asyncio.run(scenario())
    print(f"\n{change}: {messages} close {code}")
    assert [m["type"] for m in messages] == ["error"], messages
    assert "revoked" in messages[0]["reason"], messages
    assert code == 4401, code
    assert module_server.sql("SELECT COUNT(*) FROM sessions WHERE device_id = :d",
                             d=device["id"])[0][0] == 0


TINY = ("# armtrack-recording: 1\n# side: right\n# height_m: 1.75\n"
        "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
        + "".join(f"{i * 0.02:.2f},forearm,0,9.81,0,0,0,0,,,\n" for i in range(100))).encode()


def _upload(server, token: str, patient_id: int) -> httpx.Response:
    """An upload, sent again while the therapist's read turns are taken (by a probe)."""
    while True:
        answer = httpx.post(server.url + "/api/recordings", timeout=120,
                            headers={"Authorization": f"Bearer {token}"},
                            data={"patient_id": str(patient_id), "wait": "false"},
                            files={"file": ("r.csv", TINY, "text/csv")})
        if answer.status_code != 429:
            return answer


def _both_inside(server, token: str, patient_id: int, uploads, timeout: float = 60) -> None:
    """Return once the therapist's two read turns are taken (an inspection answered 429):
    only ``uploads`` hold them long, each past its checks, waiting at its first write."""
    deadline = time.monotonic() + timeout
    while True:
        answer = httpx.post(server.url + "/api/recordings/inspect", timeout=30,
                            headers={"Authorization": f"Bearer {token}"},
                            data={"patient_id": str(patient_id)},
                            files={"files": ("r.csv", TINY, "text/csv")})
        if answer.status_code == 429:
            return
        assert answer.status_code == 200, answer.text
        assert time.monotonic() < deadline and not any(u.done() for u in uploads), \
            [u.result().text for u in uploads if u.done()]
        time.sleep(0.05)


def test_an_upload_whose_patient_is_reassigned_while_it_is_read_is_not_stored(
        module_server):
    server = module_server
    alice = server.client("alice")
    patient = alice.patient("Moves while uploading")
    bob_id = server.sql("SELECT id FROM therapists WHERE username = 'bob'")[0][0]
    database = server.database_url.removeprefix("sqlite:///")
    lock = sqlite3.connect(database, timeout=30, isolation_level=None)
    try:
        lock.execute("BEGIN IMMEDIATE")  # every write of the server waits for it
        with concurrent.futures.ThreadPoolExecutor(2) as pool:
            uploads = [pool.submit(_upload, server, alice.token, patient["id"])
                       for _ in range(2)]
            _both_inside(server, alice.token, patient["id"], uploads)
            assert not any(u.done() for u in uploads), [u.result().text for u in uploads]
            # another instance reassigns the patient to bob meanwhile
            lock.execute("UPDATE patients SET therapist_id = ? WHERE id = ?",
                         (bob_id, patient["id"]))
            lock.execute("COMMIT")
            answers = [u.result() for u in uploads]
    finally:
        lock.close()
    print("\n" + "\n".join(f"{a.status_code} {a.text}" for a in answers))
    stored = server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                        p=patient["id"])[0][0]
    assert stored == 0, f"alice stored {stored} sessions in a patient no longer hers"
    for answer in answers:
        assert answer.status_code == 404, answer.text
        assert "nothing of the upload was stored" in answer.json()["detail"], answer.text
    # bob, who holds the patient now, uploads as before; alice's own patients too
    assert _upload(server, server.client("bob").token, patient["id"]).status_code == 202
    assert _upload(server, alice.token, alice.patient("Stays")["id"]).status_code == 202
