"""Kit and user input that the rest of the server cannot hold is refused where it comes in
(issue 17, item 6), on a real server:

* text that is not valid Unicode (a lone surrogate, ``"kit\\ud800x"``) in a ``hello``'s
  ``device`` or in a REST body's names, notes and passwords: refused naming the field (an
  ``error`` closing 4400, or 422), never a 500 later on the session, the patient's
  session list or the export;
* times beyond the bounds of ``docs/extensions/time-bounds.md`` (``t = 1e308`` was
  accepted and broke the session summary, the patient's summaries, the live route and
  the PDF): refused in a stream and in an uploaded recording alike, while the largest
  accepted times leave every route working.
"""

from __future__ import annotations

import asyncio
import json

import pytest
from armtrack.estimator.recording.rules import STEP_LIMIT_S, T_LIMIT_S
from server_support import PASSWORD, ServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

SURROGATE_JSON = '"kit\\ud800x"'  # JSON text: a lone surrogate escape


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("bounds"))
    server.create_user("alice")
    server.armtrack("create-user", "root", "--admin", "--password", "correct horse battery")
    server.start(timeout=120)
    yield server
    server.stop()


def post_raw(api, method: str, path: str, body: str):
    return api.http.request(method, path, content=body.encode(),
                            headers={"Content-Type": "application/json"})


@pytest.mark.parametrize("method,path,body,field", [
    ("POST", "/api/patients", '{"name": %s, "side": "right", "height_m": 1.7}', "name"),
    ("POST", "/api/patients/{pid}/devices", '{"name": %s}', "name"),
    ("PUT", "/api/patients/{pid}/targets/elbow_flexion",
     '{"min_deg": 0, "max_deg": 90, "note": %s}', "note"),
    ("POST", "/api/auth/password",
     '{"old_password": "correct horse battery", "new_password": %s}', "new_password"),
])
def test_rest_refuses_lone_surrogates_naming_the_field(srv, method, path, body, field):
    api = srv.client("alice")
    patient = api.patient(name="Surrogates")
    answer = post_raw(api, method, path.format(pid=patient["id"]),
                      body % SURROGATE_JSON.replace("kit", "kit-name-long-enough"))
    print(method, path, answer.status_code, answer.text[:300])
    assert answer.status_code == 422, answer.text
    assert field in answer.text
    json.loads(answer.text)  # a valid answer, whatever came in
    # and the lists that show such text still answer
    assert api.http.get("/api/patients").status_code == 200
    assert api.http.get(f"/api/patients/{patient['id']}/export").status_code == 200


def test_rest_refuses_control_characters_in_names(srv):
    api = srv.client("alice")
    answer = api.http.post("/api/patients", json={"name": "Ada\x00Lovelace", "side": "right",
                                                  "height_m": 1.7})
    assert answer.status_code == 422 and "name" in answer.text, answer.text
    answer = api.http.post("/api/patients", json={"name": "Ada\nLovelace", "side": "right",
                                                  "height_m": 1.7})
    assert answer.status_code == 422 and "control character" in answer.text, answer.text



@pytest.mark.parametrize("body,field", [
    ('{"name": "Ada", "side": "right", "height_m": NaN}', "height_m"),
    ('{"name": "Ada", "side": "right", "height_m": -Infinity}', "height_m"),
    ('{"name": "Ada", "side": "right", "height_m": 1.7, "note": [1e999]}', "note"),
    ('{"name": %s, "side": "right", "height_m": 1.7}' % ("[" * 500 + "]" * 500), "name"),
    ('{"name": "Ada", "side": "right", "height_m": 1.7, "x": %s}'
     % ('{"a": ' * 400 + "1" + "}" * 400), "x"),
], ids=["nan", "-inf", "inf-in-list", "500-deep", "400-deep"])
def test_a_refused_body_whose_input_json_cannot_echo_is_still_a_422(srv, body, field):
    # the 422 echoes the input it refused: NaN/Infinity (which Python's JSON reads) made
    # the answer itself fail, and so did input nested some hundreds deep (RecursionError):
    # a 500, the connection reset, and a traceback of ~100 lines in the log per request
    api = srv.client("alice")
    answer = post_raw(api, "POST", "/api/patients", body)
    print(answer.status_code, answer.text[:300])
    assert answer.status_code == 422, answer.text[:300]
    detail = json.loads(answer.text)["detail"]
    assert any(field in e["loc"] for e in detail), detail


# -- the stream ----------------------------------------------------------------------------

def hello_text(device_json: str = '"kit"', rate: int = 100) -> str:
    return ('{"type": "hello", "protocol": 1, "device": ' + device_json + ', "side": '
            '"right", "sensors": ["upper_arm"], "rate_hz": ' + str(rate)
            + ', "nine_axis": false, "resume": null}')


def row(t: float) -> list:
    return [t, 0.0, 9.81, 0.0, 0.0, 0.0, 0.0, None, None, None]


async def stream(url: str, token: str, hello: str, messages: list[dict],
                 wait_for: int) -> list[dict]:
    """Send ``hello`` then ``messages``; the answers until the ack of seq ``wait_for − 1``
    (or the close)."""
    answers: list[dict] = []
    async with connect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
        await ws.send(hello)
        try:
            answers.append(json.loads(await asyncio.wait_for(ws.recv(), 30)))
            if answers[-1]["type"] != "ready":
                await asyncio.wait_for(ws.recv(), 30)  # the close
            for message in messages:
                await ws.send(json.dumps(message))
            while messages and not any(a["type"] == "ack" and a["seq"] >= wait_for - 1
                                       for a in answers):  # acks are cumulative
                answers.append(json.loads(await asyncio.wait_for(ws.recv(), 30)))
            await ws.send(json.dumps({"type": "bye"}))
        except ConnectionClosed as closed:
            answers.append({"type": "closed", "code": closed.rcvd.code if closed.rcvd else None})
    return answers


def test_hello_refuses_a_device_name_that_is_not_text(srv):
    api = srv.client("alice")
    patient = api.patient(name="Kit surrogate")
    device = api.device(patient["id"])
    answers = asyncio.run(stream(srv.ws_url, device["token"], hello_text(SURROGATE_JSON),
                                 [], 0))
    print(answers)
    assert answers[0]["type"] == "error" and "device" in answers[0]["reason"]
    assert {"type": "closed", "code": 4400} in answers
    for path in (f"/api/patients/{patient['id']}/sessions", f"/api/patients/{patient['id']}/export",
                 f"/api/patients/{patient['id']}/summaries"):
        assert api.http.get(path).status_code == 200, path


@pytest.mark.parametrize("times,why", [
    ([0.0, 0.01, 1e308], "t"),
    ([0.0, 0.01, 0.02 + STEP_LIMIT_S * 1.5], "after"),
], ids=["1e308", "step"])
def test_a_stream_refuses_times_beyond_the_bounds(srv, times, why):
    api = srv.client("alice")
    patient = api.patient(name=f"Times {why}")
    device = api.device(patient["id"])
    messages = [{"type": "samples", "seq": 0, "sensor": "upper_arm", "rows": [row(times[0])]},
                {"type": "samples", "seq": 1, "sensor": "upper_arm", "rows": [row(times[1])]},
                {"type": "samples", "seq": 2, "sensor": "upper_arm", "rows": [row(times[2])]}]
    answers = asyncio.run(stream(srv.ws_url, device["token"], hello_text(), messages, 3))
    print(answers)
    errors = [a for a in answers if a["type"] == "error"]
    assert len(errors) == 1 and errors[0]["seq"] == 2, answers
    assert "time-bounds.md" in errors[0]["reason"], errors
    session_id = answers[0]["session"]
    for path in (f"/api/sessions/{session_id}", f"/api/sessions/{session_id}/summary",
                 f"/api/patients/{patient['id']}/summaries", f"/api/patients/{patient['id']}/live",
                 f"/api/patients/{patient['id']}/sessions"):
        answer = api.http.get(path)
        assert answer.status_code == 200, (path, answer.text[:300])


def test_the_largest_accepted_times_break_no_route(srv):
    """A kit whose clock reads near the bound, with the longest step allowed: every route
    that showed 1e308 wrong still answers."""
    api = srv.client("alice")
    patient = api.patient(name="Times at the bound")
    device = api.device(patient["id"])
    start = T_LIMIT_S - 3 * STEP_LIMIT_S
    times = [start, start + 0.01, start + 0.01 + STEP_LIMIT_S, start + 0.02 + STEP_LIMIT_S]
    messages = [{"type": "samples", "seq": i, "sensor": "upper_arm", "rows": [row(t)]}
                for i, t in enumerate(times)]
    answers = asyncio.run(stream(srv.ws_url, device["token"], hello_text(), messages, 4))
    assert not [a for a in answers if a["type"] == "error"], answers
    session_id = answers[0]["session"]
    api.http.post(f"/api/sessions/{session_id}/close")
    api.wait_processed(session_id)
    for path in (f"/api/sessions/{session_id}", f"/api/sessions/{session_id}/summary",
                 f"/api/patients/{patient['id']}/summaries", f"/api/patients/{patient['id']}/live",
                 f"/api/sessions/{session_id}/recording.csv",
                 f"/api/patients/{patient['id']}/export"):
        answer = api.http.get(path)
        assert answer.status_code == 200, (path, answer.text[:300])


# -- recording files ---------------------------------------------------------------------

HEADER = ("# armtrack-recording: 1\n# side: right\n# height_m: 1.7\n"
          "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n")


@pytest.mark.parametrize("times,line,words", [
    (("0.0", "0.01", "1e308"), 7, "beyond the time bounds"),
    (("-2e10", "-2e10", "-2e10"), 5, "beyond the time bounds"),
    (("0.0", "0.01", repr(0.02 + STEP_LIMIT_S * 1.5)), 7, "after its previous sample"),
], ids=["1e308", "far-negative", "step"])
def test_an_upload_refuses_times_beyond_the_bounds(srv, times, line, words):
    api = srv.client("alice")
    patient = api.patient(name="Upload times")
    text = HEADER + "".join(f"{t},upper_arm,0,9.81,0,0,0,0,,,\n" for t in times)
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("far.csv", text)})
    print(answer.status_code, answer.text)
    assert answer.status_code == 422, answer.text
    assert f"line {line}" in answer.text and words in answer.text
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


def test_an_upload_refuses_marks_beyond_the_bounds(srv):
    api = srv.client("alice")
    patient = api.patient(name="Upload marks")
    text = (HEADER.replace("t,sensor", "# marks: 1e308 exercise:elbow_flexion\nt,sensor")
            + "0.0,upper_arm,0,9.81,0,0,0,0,,,\n")
    answer = api.http.post("/api/recordings", data={"patient_id": str(patient["id"])},
                           files={"file": ("marks.csv", text)})
    assert answer.status_code == 422 and "time bounds" in answer.text, answer.text


def test_hello_refuses_a_program_name_that_is_not_text(srv):
    """``programs/1``: a ``hello`` naming its program by a name holding a lone surrogate
    went to the database as it was: SQLite's driver raised UnicodeEncodeError inside the
    handler, the socket dropped without a close frame (1006) and the kit learnt nothing.
    Now refused like any malformed hello, naming the field (4400)."""
    api = srv.client("alice")
    patient = api.patient(name="Program surrogate")
    device = api.device(patient["id"])
    hello = hello_text().replace(', "resume": null}', ', "resume": null, "extensions": '
                                 '["programs/1"], "program": ' + SURROGATE_JSON + '}')
    answers = asyncio.run(stream(srv.ws_url, device["token"], hello, [], 0))
    print(answers)
    assert answers[0]["type"] == "error" and "program" in answers[0]["reason"], answers
    assert {"type": "closed", "code": 4400} in answers
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []


@pytest.mark.parametrize("rid", [SURROGATE_JSON, '"kit\\u0000x"'], ids=["surrogate", "nul"])
def test_an_effort_rating_whose_id_is_not_text_is_refused_and_the_stream_goes_on(srv, rid):
    """``effort-pain/1``: a rating whose ``id`` held a lone surrogate reached the database:
    the handler died on UnicodeEncodeError, the stream ended without its ack nor an
    error, and the session was left 'interrupted'. (A NUL is refused too: PostgreSQL
    cannot store one.) Now the protocol's ``error`` names ``id``, and the stream goes on."""
    api = srv.client("alice")
    patient = api.patient(name=f"Rating id {rid[5:9]}")
    device = api.device(patient["id"])
    hello = hello_text().replace(', "resume": null}', ', "resume": null, "extensions": '
                                 '["effort-pain/1"]}')
    bad = ('{"type": "effort_pain", "id": ' + rid + ', "exercise": "elbow_flexion", '
           '"effort": 3}')

    async def run() -> list[dict]:
        answers: list[dict] = []
        async with connect(srv.ws_url,
                           additional_headers={"Authorization": f"Bearer {device['token']}"}
                           ) as ws:
            await ws.send(hello)
            answers.append(json.loads(await asyncio.wait_for(ws.recv(), 30)))
            await ws.send(json.dumps({"type": "samples", "seq": 0, "sensor": "upper_arm",
                                      "rows": [row(0.0)]}))
            await ws.send(bad)
            await ws.send(json.dumps({"type": "samples", "seq": 1, "sensor": "upper_arm",
                                      "rows": [row(0.01)]}))
            try:
                while not any(a["type"] == "ack" and a["seq"] >= 1 for a in answers):
                    answers.append(json.loads(await asyncio.wait_for(ws.recv(), 30)))
                await ws.send(json.dumps({"type": "bye"}))
                await asyncio.wait_for(ws.wait_closed(), 30)
                answers.append({"type": "closed", "code": ws.close_code})
            except ConnectionClosed as closed:
                answers.append({"type": "closed",
                                "code": closed.rcvd.code if closed.rcvd else None})
        return answers

    answers = asyncio.run(run())
    print(answers)
    errors = [a for a in answers if a["type"] == "error"]
    assert len(errors) == 1 and "effort_pain: id" in errors[0]["reason"], answers
    assert errors[0]["seq"] is None
    assert any(a["type"] == "ack" and a["seq"] == 1 for a in answers), answers
    assert answers[-1] == {"type": "closed", "code": 1000}, answers
    session = api.http.get(f"/api/sessions/{answers[0]['session']}").json()
    print(session["status"], session["samples"])
    assert session["status"] == "closed" and session["samples"] == 2


@pytest.mark.parametrize("who,path,body", [
    ("alice", "/api/auth/password", {"old_password": PASSWORD, "new_password": "S3cr-t"}),
    ("alice", "/api/auth/password", {"current_password": PASSWORD,
                                     "new_password": "S3cr-t but long enough"}),
    ("root", "/api/admin/therapists", {"username": "newbie", "password": "S3cr-t"}),
])
def test_a_refused_password_is_not_echoed_in_the_422(srv, who, path, body):
    """attack13: a 422 echoes the refused input, and so it sent back the passwords of a
    refused password change (the new one too short; a field misnamed: the whole body,
    the current password in it) or of a new account, to land in whatever keeps response
    bodies (a proxy's log, the browser's). Secret fields are now shown as ***."""
    answer = srv.client(who).http.post(path, json=body)
    print(f"\n{path}: {answer.status_code} {answer.text[:300]}")
    assert answer.status_code == 422
    assert "S3cr-t" not in answer.text and PASSWORD not in answer.text
    assert "***" in answer.text  # the field is still named, its value hidden
