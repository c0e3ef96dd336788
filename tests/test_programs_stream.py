"""The programs' stream extensions on a real server with a real WebSocket
(``docs/extensions/programs-hello.md``, ``docs/extensions/effort-pain.md``): a kit names a
program and gets its exercises and version; a resumed stream keeps the version it began
with after the program changed; an unknown or ended program still streams, saying why;
effort and pain are checked whole, stored once however often sent, and shown in the
program's progress; a kit that asks for nothing sees nothing new."""

from __future__ import annotations

import asyncio
import json
from types import SimpleNamespace

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

PROGRAM = {"name": "Home elbow", "start_date": "2020-01-01", "exercises": [
    {"exercise": "elbow_flexion", "sets": 2, "repetitions": 8, "days_per_week": 5}]}


def hello(**extra) -> str:
    return json.dumps({"type": "hello", "protocol": 1, "device": "t", "side": "right",
                       "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False,
                       "resume": None, **extra})


async def exchange(server, token: str, *messages: str, replies: int = 1) -> list[dict]:
    """Send ``messages`` one by one, reading ``replies`` answers after each (the first is
    ``hello``'s ``ready``); returns every answer; the connection is left without bye."""
    got = []
    async with connect(server.ws_url, additional_headers={
            "Authorization": f"Bearer {token}"}) as ws:
        for message in messages:
            await ws.send(message)
            for _ in range(replies):
                try:
                    got.append(json.loads(await asyncio.wait_for(ws.recv(), 10)))
                except ConnectionClosed as exc:
                    got.append({"closed": exc.rcvd.code if exc.rcvd else None,
                                "reason": exc.rcvd.reason if exc.rcvd else ""})
                    return got
    return got


@pytest.fixture(scope="module")
def setup(module_server):
    alice = module_server.client("alice")
    patient = alice.patient("Streamer")
    device = alice.device(patient["id"], "kit")
    program = alice.http.post(f"/api/patients/{patient['id']}/programs", json=PROGRAM).json()
    return SimpleNamespace(server=module_server, alice=alice, patient=patient,
                           device=device, program=program)


def test_a_kit_that_names_the_program_gets_its_exercises_and_version(setup):
    w = setup
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1", "effort-pain/1", "future-thing/3"], program="Home elbow")))
    assert ready["extensions"] == ["programs/1", "effort-pain/1"]  # what it speaks
    assert ready["program"]["id"] == w.program["id"] and ready["program"]["version"] == 1
    (exercise,) = ready["program"]["exercises"]
    assert exercise["name"] == "elbow_flexion" and exercise["angle"] == "elbow_flexion"
    assert (exercise["sets"], exercise["repetitions"]) == (2, 8)
    assert exercise["target"] == {"min_deg": 0.0, "max_deg": 120.0, "from": "catalogue"}
    # by id too
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program=w.program["id"])))
    assert ready["program"]["name"] == "Home elbow"


def test_a_resumed_stream_keeps_the_version_it_began_with(setup):
    w = setup
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program="Home elbow")))
    version = ready["program"]["version"]
    changed = w.alice.http.put(f"/api/programs/{w.program['id']}", json={
        **{k: v for k, v in PROGRAM.items() if k != "name"},
        "exercises": [{**PROGRAM["exercises"][0], "sets": 3}]})
    assert changed.json()["version"]["number"] == version + 1
    (again,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program="Home elbow", resume=ready["stream"])))
    assert again["session"] == ready["session"]
    assert again["program"]["version"] == version  # not the newer one
    assert again["program"]["exercises"][0]["sets"] == 2
    (new,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program="Home elbow")))
    assert new["program"]["version"] == version + 1


def test_an_unknown_or_ended_program_streams_all_the_same_saying_why(setup):
    w = setup
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program="Nothing like it")))
    assert ready["program"] is None and ready["session"]
    assert ready["program_error"] == "no program 'Nothing like it' for this device's patient"
    other = w.alice.patient("Someone else")
    theirs = w.alice.http.post(f"/api/patients/{other['id']}/programs", json={
        **PROGRAM, "name": "Theirs"}).json()
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program=theirs["id"])))
    assert ready["program"] is None  # another patient's w.program is not this kit's
    made = w.alice.http.post(f"/api/patients/{w.patient['id']}/programs", json={
        **PROGRAM, "name": "Over"}).json()
    w.alice.http.post(f"/api/programs/{made['id']}/end")
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program="Over")))
    assert ready["program"] is None and ready["program_error"] == "program 'Over' has ended"
    # a malformed w.program is a malformed hello
    (error, closed) = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1"], program=["a list"]), replies=2))
    assert error["type"] == "error" and "program must be a program's id" in error["reason"]
    assert closed["closed"] == 4400


def test_a_kit_that_asks_for_nothing_sees_nothing_new(setup):
    w = setup
    (ready,) = asyncio.run(exchange(w.server, w.device["token"], hello(program="Home elbow")))
    assert set(ready) == {"type", "stream", "session", "next_seq"}


@pytest.mark.parametrize(("rating", "words"), [
    ({"id": "", "exercise": "elbow_flexion", "pain": 1}, "id must be"),
    ({"id": "x" * 65, "exercise": "elbow_flexion", "pain": 1}, "id must be"),
    ({"id": "a", "exercise": "elbow flexion!", "pain": 1}, "exercise must be"),
    ({"id": "a", "exercise": "elbow_flexion", "pain": 11}, "pain must be a whole number"),
    ({"id": "a", "exercise": "elbow_flexion", "pain": 2.5}, "pain must be a whole number"),
    ({"id": "a", "exercise": "elbow_flexion", "pain": True}, "pain must be a whole number"),
    ({"id": "a", "exercise": "elbow_flexion", "effort": 4.2}, "steps of 0.5"),
    ({"id": "a", "exercise": "elbow_flexion", "effort": -1}, "steps of 0.5"),
    ({"id": "a", "exercise": "elbow_flexion"}, "give effort, pain or both"),
    ({"id": "a", "exercise": "elbow_flexion", "pain": 1, "t": "soon"}, "t must be"),
])
def test_a_bad_rating_is_refused_naming_the_field(setup, rating, words):
    w = setup
    ready, error = asyncio.run(exchange(
        w.server, w.device["token"], hello(extensions=["effort-pain/1"]),
        json.dumps({"type": "effort_pain", **rating})))
    assert error["type"] == "error" and error["seq"] is None, error
    assert error["reason"].startswith("effort_pain: ") and words in error["reason"]
    rows = w.server.sql("SELECT count(*) FROM session_ratings WHERE session_id = :s",
                      s=ready["session"])
    assert rows == [(0,)]


def test_a_rating_is_stored_once_however_often_sent(setup):
    w = setup
    rating = json.dumps({"type": "effort_pain", "id": "r1", "exercise": "elbow_flexion",
                         "t": 30.5, "effort": 4.5, "pain": 3})
    second = json.dumps({"type": "effort_pain", "id": "r1", "exercise": "elbow_flexion",
                         "effort": 9, "pain": 9})
    ready, one, two = asyncio.run(exchange(w.server, w.device["token"], hello(
        extensions=["programs/1", "effort-pain/1"], program="Home elbow"), rating, second))
    assert one == two == {"type": "effort_pain_stored", "id": "r1"}
    rows = w.server.sql("SELECT rating_id, exercise, t, effort, pain FROM session_ratings "
                      "WHERE session_id = :s", s=ready["session"])
    assert rows == [("r1", "elbow_flexion", 30.5, 4.5, 3)]  # the first one stands
    pain = w.alice.http.get(f"/api/programs/{w.program['id']}/adherence").json()["pain"]
    assert {"session_id": ready["session"], "pain": 3, "effort": 4.5} in [
        {k: p[k] for k in ("session_id", "pain", "effort")} for p in pain]


def test_a_session_keeps_a_bounded_number_of_ratings(setup):
    """A kit flooding ratings with new ids fills no table: past the most a session keeps
    (``RATINGS_PER_SESSION_MAX``) a rating is refused naming the limit, nothing stored,
    the connection open; a rating sent again under a stored id is still answered stored."""
    from armtrack.server.programs.stream import RATINGS_PER_SESSION_MAX

    w = setup
    ratings = [json.dumps({"type": "effort_pain", "id": f"r{i}", "exercise": "elbow_flexion",
                           "pain": 1}) for i in range(RATINGS_PER_SESSION_MAX + 1)]
    answers = asyncio.run(exchange(w.server, w.device["token"],
                                   hello(extensions=["effort-pain/1"]), *ratings, ratings[0]))
    ready, stored, over, again = answers[0], answers[1:-2], answers[-2], answers[-1]
    assert all(a["type"] == "effort_pain_stored" for a in stored), stored[-1]
    assert over["type"] == "error" and over["seq"] is None, over
    assert over["reason"].startswith("effort_pain: ") and str(RATINGS_PER_SESSION_MAX) in \
        over["reason"], over
    assert again == {"type": "effort_pain_stored", "id": "r0"}
    rows = w.server.sql("SELECT count(*) FROM session_ratings WHERE session_id = :s",
                        s=ready["session"])
    assert rows == [(RATINGS_PER_SESSION_MAX,)]
