"""Security review (Low): one kit token started 300 sessions in 46 s, after which its
patient's progress report took 6 s (it grows with the sessions). A kit starts at most
``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR`` new sessions an hour (here 3): the next hello
without resume or session gets the protocol's ``error`` naming the limit and close
``4429``, nothing stored. Resuming a stream and a new stream in a session are no new
sessions; a closed session's rest (closed-session/1) is one, refused at the limit and
taken once the hour has passed (the kit keeps it meanwhile). Other kits are not limited.
A kit's uploads are new sessions too, counted with its streams by when they arrived.
Real server, real WebSocket client, real database file."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from server_support import ServerProcess
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

LIMIT = 3
HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("flood"), env={
        "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR": str(LIMIT)})
    server.create_user("alice")
    server.start()
    yield server
    server.stop()


def samples(seq: int, t0: float) -> str:
    rows = [[t0 + i / 50, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, None, None, None] for i in range(10)]
    return json.dumps({"type": "samples", "seq": seq, "sensor": "forearm", "rows": rows})


async def hello(srv, token: str, **fields) -> tuple[object, dict]:
    """Connect and say hello: (the socket, the first answer, or {"closed": code})."""
    ws = await connect(srv.ws_url, additional_headers={"Authorization": f"Bearer {token}"})
    await ws.send(json.dumps({**HELLO, **fields}))
    try:
        return ws, json.loads(await asyncio.wait_for(ws.recv(), 10))
    except ConnectionClosed as exc:
        return ws, {"closed": exc.rcvd.code if exc.rcvd else None}


async def closing_code(ws) -> int | None:
    try:
        await asyncio.wait_for(ws.recv(), 10)
    except ConnectionClosed as exc:
        return exc.rcvd.code if exc.rcvd else None
    return None


async def send_acked(ws, seq: int, t0: float) -> None:
    await ws.send(samples(seq, t0))
    while True:
        answer = json.loads(await asyncio.wait_for(ws.recv(), 10))
        if answer["type"] == "ack" and answer["seq"] >= seq:
            return
        assert answer["type"] != "error", answer


def test_a_kit_starts_a_bounded_number_of_new_sessions(srv):
    alice = srv.client("alice")
    patient = alice.patient("Flood")
    token = alice.device(patient["id"])["token"]
    other = alice.device(alice.patient("Other")["id"])["token"]
    stored = lambda: srv.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",  # noqa: E731
                             p=patient["id"])[0][0]

    async def scenario():
        first_ws, first = await hello(srv, token)
        assert first["type"] == "ready", first
        await send_acked(first_ws, 0, 0.0)
        await first_ws.close()  # lost, no bye: the session waits for its resume
        for _ in range(LIMIT - 1):
            ws, ready = await hello(srv, token)
            assert ready["type"] == "ready", ready
            await ws.send(json.dumps({"type": "bye"}))
            await ws.close()
        ws, refused = await hello(srv, token)
        print(f"\nnew session {LIMIT + 1} of one kit in an hour: {refused}")
        assert refused.get("type") == "error" and refused["seq"] is None, refused
        refused_code = await closing_code(ws)
        assert "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR" in refused["reason"], refused
        assert f"= {LIMIT}" in refused["reason"], refused
        assert refused_code == 4429
        assert stored() == LIMIT  # nothing stored of the refused one

        # another kit is not limited by this one's sessions
        ws, ready = await hello(srv, other)
        assert ready["type"] == "ready", ready
        await ws.send(json.dumps({"type": "bye"}))
        await ws.close()

        # a reconnect resumes its stream: no new session, not refused
        ws, resumed = await hello(srv, token, resume=first["stream"])
        assert resumed["type"] == "ready" and resumed["next_seq"] == 1, resumed
        await send_acked(ws, 1, 0.2)
        await ws.close()
        # a new stream in the session (a kit whose clock restarted): no new session either
        ws, continued = await hello(srv, token, session=first["session"])
        assert continued["type"] == "ready" and continued["session"] == first["session"], \
            continued
        await send_acked(ws, 0, 0.0)
        await ws.close()
        assert stored() == LIMIT

        # the therapist closes the session while the kit is away: its resume is refused
        # with what is stored (closed-session/1); the rest would be a new session, refused
        # at the limit (the kit keeps it) and taken once the hour has passed
        closed = alice.http.post(f"/api/sessions/{first['session']}/close")
        assert closed.status_code == 200, closed.text
        ws, gone = await hello(srv, token, resume=continued["stream"],
                               extensions=["closed-session/1"])
        assert gone.get("type") == "error" and gone.get("next_seq") == 1, gone
        await ws.close()
        ws, refused_rest = await hello(srv, token, extensions=["closed-session/1"])
        assert refused_rest.get("type") == "error", refused_rest
        assert "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR" in refused_rest["reason"]
        await ws.close()
        assert stored() == LIMIT
        hour_ago = (datetime.now(UTC) - timedelta(hours=1, minutes=1)).strftime(
            "%Y-%m-%d %H:%M:%S.%f")
        srv.sql("UPDATE sessions SET started_at = :t, created_at = :t WHERE patient_id = :p",
                t=hour_ago, p=patient["id"])
        ws, rest = await hello(srv, token, extensions=["closed-session/1"])
        assert rest["type"] == "ready" and rest["session"] != first["session"], rest
        await send_acked(ws, 0, 0.4)
        await ws.send(json.dumps({"type": "bye"}))
        await ws.close()
        assert stored() == LIMIT + 1

    asyncio.run(scenario())


def kit_upload(srv, token: str, data: bytes, name: str = "offline.csv"):
    return httpx.post(f"{srv.url}/api/recordings", headers={"Authorization": f"Bearer {token}"},
                      data={"wait": "false"}, files={"file": (name, data)}, timeout=120)


def dated(recording: bytes, moment: datetime) -> bytes:
    """The recording with a start_time header (docs/extensions/start-time.md)."""
    lines = recording.split(b"\n")
    columns = next(i for i, line in enumerate(lines) if line.startswith(b"t,"))
    lines.insert(columns, f"# start_time: {moment.isoformat()}".encode())
    return b"\n".join(lines)


def test_uploads_with_a_kit_token_count_as_its_new_sessions(srv, recordings_dir):
    """A kit's token may also upload recordings (``POST /api/recordings``): each is a new
    session of the kit, counted with its streamed ones, whenever the file says it was
    recorded; over the limit the upload is refused (429 naming the setting), nothing
    stored, and so is the next streamed session. A therapist's upload is not a kit's."""
    alice = srv.client("alice")
    patient = alice.patient("Uploads")
    token = alice.device(patient["id"])["token"]
    recording = (recordings_dir / "left_reach_50hz.csv").read_bytes()
    stored = lambda: srv.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",  # noqa: E731
                             p=patient["id"])[0][0]
    blocks = lambda: srv.sql("SELECT count(*) FROM sample_blocks")[0][0]  # noqa: E731

    week_ago = datetime.now(UTC) - timedelta(days=7)
    for data in (recording, dated(recording, week_ago)):  # recorded long ago: counts too
        answer = kit_upload(srv, token, data)
        assert answer.status_code == 202, answer.text

    async def one_stream() -> dict:
        ws, answer = await hello(srv, token)
        if answer.get("type") == "ready":
            await ws.send(json.dumps({"type": "bye"}))
        await ws.close()
        return answer

    assert asyncio.run(one_stream())["type"] == "ready"  # the third new session
    assert stored() == LIMIT
    before = blocks()
    refused = kit_upload(srv, token, recording)
    print(f"\nupload {LIMIT + 1} of one kit in an hour: {refused.status_code} {refused.text}")
    assert refused.status_code == 429, refused.text
    assert "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR" in refused.json()["detail"]
    assert f"= {LIMIT}" in refused.json()["detail"]
    assert stored() == LIMIT and blocks() == before  # nothing stored in part
    streamed = asyncio.run(one_stream())  # the kit's uploads count for its streams too
    assert streamed.get("type") == "error" and "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR" \
        in streamed["reason"], streamed
    # the therapist's own upload for the patient is not the kit's
    answer = alice.http.post("/api/recordings", data={"patient_id": patient["id"],
                                                      "wait": "false"},
                             files={"file": ("clinic.csv", recording)})
    assert answer.status_code == 202, answer.text
    # an hour later the kit may again
    hour_ago = (datetime.now(UTC) - timedelta(hours=1, minutes=1)).strftime(
        "%Y-%m-%d %H:%M:%S.%f")
    srv.sql("UPDATE sessions SET started_at = :t WHERE patient_id = :p AND source = 'stream'",
            t=hour_ago, p=patient["id"])
    srv.sql("UPDATE sessions SET created_at = :t WHERE patient_id = :p", t=hour_ago,
            p=patient["id"])
    answer = kit_upload(srv, token, recording)
    assert answer.status_code == 202, answer.text
    assert stored() == LIMIT + 2
