"""A hostile kit's marks, on a real server with a real WebSocket client: a mark's label
and a session's number of marks are bounded, so a kit cannot grow the server's memory
(each feedback stream keeps the marks it saw) nor the database and the therapist's
session pages without end. Before: 300 marks of 1 MB labels grew the server by +536 MiB
and stored 300 MB of labels."""

from __future__ import annotations

import asyncio
import json

import pytest
from server_support import ServerProcess
from websockets.asyncio.client import connect

LABEL_MAX = 100
MARKS_MAX = 1000


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("marks"))
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


HELLO = {"type": "hello", "protocol": 1, "device": "phone", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None,
         "extensions": ["feedback/1"]}


async def send_marks(url: str, labels: list[str], hello: dict | None = None,
                     bye: bool = True) -> tuple[dict, list[dict]]:
    """``labels`` as marks (t 1 s apart, far ahead of any pose), then bye (or, without,
    a close once the last is acked: the session stays open to go on); the ready and every
    error the server answered."""
    errors = []
    async with connect(url, max_size=None) as ws:
        await ws.send(json.dumps(hello or HELLO))
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        last = ready["next_seq"] + len(labels) - 1
        for seq, label in enumerate(labels, start=ready["next_seq"]):
            await ws.send(json.dumps({"type": "mark", "seq": seq, "t": 1e6 + seq,
                                      "label": label}))
        if bye:
            await ws.send(json.dumps({"type": "bye"}))
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "error":
                errors.append(message)
            if not bye and message["type"] == "ack" and message["seq"] >= last:
                break
    return ready, errors


def test_a_mark_label_longer_than_the_limit_is_refused_naming_it(server):
    api = server.client("alice")
    patient = api.patient("Long marks")
    kit = api.device(patient["id"], "phone")
    url = f"{server.ws_url}?token={kit['token']}"
    before = rss_mb(server.process.pid)
    long = "exercise:" + "a" * 1_000_000
    ready, errors = asyncio.run(send_marks(url, [long] * 40 + ["exercise:elbow_flexion"]))
    grown = rss_mb(server.process.pid) - before
    stored = server.sql("SELECT COUNT(*), MAX(LENGTH(label)) FROM marks WHERE session_id = :s",
                        s=ready["session"])[0]
    print(f"40 marks of 1 MB: {len(errors)} refused, stored {stored}, server +{grown:.0f} MiB; "
          f"{errors[0]['reason'][:120] if errors else None}")
    assert len(errors) == 40 and all(str(LABEL_MAX) in e["reason"] for e in errors), errors[:1]
    assert all(len(e["reason"]) < 300 for e in errors)  # the label is not echoed whole
    assert stored == (1, len("exercise:elbow_flexion"))
    assert grown < 30


def test_a_session_keeps_at_most_its_number_of_marks_across_streams(server):
    api = server.client("alice")
    patient = api.patient("Many marks")
    kit = api.device(patient["id"], "phone")
    url = f"{server.ws_url}?token={kit['token']}"
    first = [f"exercise:e{k}" for k in range(MARKS_MAX - 10)]
    ready, errors = asyncio.run(send_marks(url, first, bye=False))
    assert not errors, errors[:1]
    more = [f"exercise:f{k}" for k in range(30)]  # a new stream in the same session
    _, errors = asyncio.run(send_marks(url, more, {**HELLO, "session": ready["session"]}))
    stored = server.sql("SELECT COUNT(*) FROM marks WHERE session_id = :s",
                        s=ready["session"])[0][0]
    print(f"{len(first)} + {len(more)} marks: stored {stored}, refused {len(errors)}: "
          f"{errors[0]['reason'] if errors else None}")
    assert stored == MARKS_MAX
    assert len(errors) == 20 and all(str(MARKS_MAX) in e["reason"] for e in errors)


def test_an_effort_rating_naming_an_exercise_longer_than_a_mark_is_refused(server):
    """A rating's ``exercise`` is a mark's name: 200 ratings of 1 MB names were 200 MB of
    one session (and the refusal of a bad one echoed the name whole)."""
    api = server.client("alice")
    patient = api.patient("Long rating")
    kit = api.device(patient["id"], "phone")

    async def run():
        hello = {**HELLO, "extensions": ["feedback/1", "effort-pain/1"]}
        async with connect(f"{server.ws_url}?token={kit['token']}", max_size=None) as ws:
            await ws.send(json.dumps(hello))
            ready = json.loads(await ws.recv())
            await ws.send(json.dumps({"type": "effort_pain", "id": "r1", "effort": 3,
                                      "exercise": "a" * 1_000_000}))
            answer = json.loads(await ws.recv())
            await ws.send(json.dumps({"type": "effort_pain", "id": "r2", "effort": 3,
                                      "exercise": "elbow_flexion"}))
            stored = json.loads(await ws.recv())
            return ready, answer, stored

    ready, answer, stored = asyncio.run(run())
    print(answer["reason"][:200], stored)
    assert answer["type"] == "error" and str(LABEL_MAX) in answer["reason"], answer
    assert len(answer["reason"]) < 300
    assert stored == {"type": "effort_pain_stored", "id": "r2"}
    assert server.sql("SELECT COUNT(*) FROM session_ratings WHERE session_id = :s",
                      s=ready["session"])[0][0] == 1
