"""A session holds at most ``ARMTRACK_MAX_SESSION_SAMPLES`` samples, streamed or
uploaded, on a real server: a kit cannot make one session that the estimation, once the
session is closed, cannot hold in memory.

The attack that worked: one kit token streamed 1000-row messages as fast as it could for
20 s (t running 1200× faster than a clock, each message well formed): 7.3 million rows
stored in one session, and closing it (the therapist's routine click) took the processing
process from 0.4 to 4.95 GB of memory for 52 s; a minute of it would have exhausted the
23 GB machine. An upload was no better bound: a 200 MB file of short rows holds about as
many. Now the message that would pass the limit is refused with the protocol's ``error``
naming the setting (its number used up, the stream open: what came before stays stored),
and an upload over it is refused (413) naming it, nothing stored."""

from __future__ import annotations

import asyncio
import json

import httpx
from server_support import server_fixture
from websockets.asyncio.client import connect

LIMIT = 5000
server = server_fixture("session_size", "alice",
                        env={"ARMTRACK_MAX_SESSION_SAMPLES": str(LIMIT)})

HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["upper_arm", "forearm"], "rate_hz": 100, "nine_axis": False,
         "resume": None}


def rows(t0: float, n: int) -> list[list]:
    return [[t0 + i * 0.01, 0.0, 9.81, 0.0, 0.0, 0.0, 0.0, None, None, None]
            for i in range(n)]


async def stream(url: str, messages: list[dict], hello: dict | None = None,
                 bye: bool = True) -> tuple[dict, list[dict], int | None]:
    """``messages`` numbered from the ready's next_seq, then bye (or, without, the
    connection dropped once the last is acked: the session stays open to resume); the
    ready, the errors and the close code."""
    errors = []
    async with connect(url, max_size=None) as ws:
        await ws.send(json.dumps(hello or HELLO))
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        last = ready["next_seq"] + len(messages) - 1
        for seq, message in enumerate(messages, start=ready["next_seq"]):
            await ws.send(json.dumps({**message, "seq": seq}))
        if bye:
            await ws.send(json.dumps({"type": "bye"}))
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "error":
                errors.append(message)
            if not bye and message["type"] == "ack" and message["seq"] >= last:
                break
    return ready, errors, ws.close_code


def test_a_stream_stores_at_most_the_limit_of_samples_in_a_session(server):
    api = server.client("alice")
    patient = api.patient("Flood")
    kit = api.device(patient["id"])
    url = f"{server.ws_url}?token={kit['token']}"
    # 4999 rows fit; 1000 more would pass 5000 (refused), and so is every later message
    # of the stream, the 1 row that would fit too: the kit sends them all, from the first
    # refused one on, as a new session (a row stored here too would be stored twice)
    messages = [{"type": "samples", "sensor": sensor, "rows": rows(t0, n)} for sensor, t0, n in (
        ("upper_arm", 0, 1000), ("forearm", 0, 1000), ("upper_arm", 10, 1000),
        ("forearm", 10, 1000), ("upper_arm", 20, 999), ("upper_arm", 30, 1000),
        ("upper_arm", 40, 1), ("forearm", 50, 1))]
    ready, errors, code = asyncio.run(stream(url, messages, bye=False))
    stored = server.sql("SELECT samples FROM sessions WHERE id = :s", s=ready["session"])[0][0]
    print(f"sent 6001 rows, limit {LIMIT}: stored {stored}, errors "
          f"{[(e['seq'], e['reason'][:100]) for e in errors]}, close {code}")
    assert [e["seq"] for e in errors] == [5, 6, 7], errors
    assert all("(ARMTRACK_MAX_SESSION_SAMPLES): start a new session" in e["reason"]
               for e in errors), errors
    assert stored == 4999
    # a resume of the session is bound by what it holds already
    resumed = dict(HELLO, resume=ready["stream"])
    again, errors, code = asyncio.run(stream(url, [
        {"type": "samples", "sensor": "forearm", "rows": rows(60, 2)}], resumed))
    print("resumed:", again, [e["reason"][:60] for e in errors], code)
    assert again["session"] == ready["session"] and again["next_seq"] == len(messages)
    assert [e["seq"] for e in errors] == [again["next_seq"]], errors
    assert code == 1000
    # a new session starts empty
    fresh, errors, _ = asyncio.run(stream(url, [
        {"type": "samples", "sensor": "forearm", "rows": rows(0, 1000)}]))
    assert errors == [] and fresh["session"] != ready["session"]
    assert server.sql("SELECT samples FROM sessions WHERE id = :s",
                      s=fresh["session"])[0][0] == 1000


def recording(n_rows: int) -> bytes:
    lines = ["# armtrack-recording: 1", "# side: right", "# height_m: 1.75",
             "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz"]
    lines += [f"{i * 0.01:.2f},forearm,0,9.81,0,0,0,0,,," for i in range(n_rows)]
    return ("\n".join(lines) + "\n").encode()


def test_an_upload_over_the_limit_is_refused_naming_it(server):
    api = server.client("alice")
    patient = api.patient("Big upload")
    kit = api.device(patient["id"])
    for who, token in (("kit", kit["token"]), ("therapist", api.token)):
        answer = httpx.post(server.url + "/api/recordings",
                            headers={"Authorization": f"Bearer {token}"},
                            data={} if who == "kit" else {"patient_id": str(patient["id"])},
                            files={"file": ("big.csv", recording(LIMIT + 1), "text/csv")},
                            timeout=120)
        print(who, answer.status_code, answer.text[:200])
        assert answer.status_code == 413, answer.text
        assert "ARMTRACK_MAX_SESSION_SAMPLES" in answer.json()["detail"]
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []
    answer = httpx.post(server.url + "/api/recordings",
                        headers={"Authorization": f"Bearer {kit['token']}"},
                        files={"file": ("ok.csv", recording(LIMIT), "text/csv")}, timeout=120)
    assert answer.status_code == 201, answer.text
    assert answer.json()["samples"] == LIMIT
