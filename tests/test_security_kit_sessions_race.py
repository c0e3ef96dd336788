"""Security review (Low): a kit's new sessions an hour (``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR``)
were counted apart by a stream's hello and by an upload with the kit's token, each before
storing its session: a hello arriving while an upload of the same kit was being parsed
(after its count, before its store) passed the count too, and the kit had limit + 1
sessions in the hour. And the "another upload from this kit is being stored" guard held
in one server process only: a second instance on the same PostgreSQL took a second upload
of the kit at once. Now the count and the new session's insert are one step per kit in
the database, whichever path and instance, and the guard is the database's too.

Real ``armtrack serve`` processes, real WebSocket and HTTP clients, a real SQLite file or
PostgreSQL (``ARMTRACK_TEST_POSTGRES_URL``, ``eval "$(.ci/postgres start)"``)."""

from __future__ import annotations

import asyncio
import json
import time

import httpx
import pytest
from conftest import fresh_postgres_database
from server_support import ServerProcess
from test_security_upload_burst import still_recording
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

LIMIT = 3
SETTING = "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR"
HELLO = {"type": "hello", "protocol": 1, "device": "kit", "side": "right",
         "sensors": ["forearm"], "rate_hz": 50, "nine_axis": False, "resume": None}


@pytest.fixture(params=["sqlite", "postgres"])
def database_env(request) -> dict[str, str]:
    if request.param == "sqlite":
        return {}
    return {"ARMTRACK_DATABASE_URL": fresh_postgres_database(
        request.getfixturevalue("postgres_url"))}


def _server(folder, env: dict[str, str]) -> ServerProcess:
    return ServerProcess(folder, {SETTING: str(LIMIT), **env})


async def _big_upload_then(url: str, token: str, big: bytes, then):
    """POST ``big`` with the kit's token, its body in 1 MiB pieces; 0.3 s after the last
    piece (the server is parsing it) ``then()`` runs. (the upload's answer, then's)."""
    kit = {"Authorization": f"Bearer {token}"}
    async with httpx.AsyncClient(base_url=url, timeout=300) as http:
        request = http.build_request("POST", "/api/recordings", headers=kit,
                                     data={"wait": "false"}, files={"file": ("long.csv", big)})
        body, sent = request.read(), asyncio.Event()

        async def pieces():
            for at in range(0, len(body), 1 << 20):
                yield body[at:at + (1 << 20)]
            sent.set()

        upload = asyncio.create_task(http.post("/api/recordings", content=pieces(), headers={
            **kit, "Content-Type": request.headers["Content-Type"],
            "Content-Length": str(len(body))}))
        await sent.wait()
        await asyncio.sleep(0.3)
        assert not upload.done(), "the upload was stored before the race: no race tested"
        began = time.monotonic()
        other = await then()
        took = time.monotonic() - began
        return await upload, other, took


def test_a_hello_racing_an_upload_of_the_same_kit_cannot_pass_the_limit(tmp_path,
                                                                        database_env):
    srv = _server(tmp_path / "race", database_env)
    srv.create_user("alice")
    srv.start()
    try:
        alice = srv.client("alice")
        patient = alice.patient("Racing")
        token = alice.device(patient["id"])["token"]
        stored = lambda: srv.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",  # noqa: E731
                                 p=patient["id"])[0][0]
        small = still_recording(5)
        for i in range(LIMIT - 1):  # the kit's sessions of the hour but one
            answer = httpx.post(f"{srv.url}/api/recordings",
                                headers={"Authorization": f"Bearer {token}"},
                                data={"wait": "false"}, files={"file": (f"s{i}.csv", small)},
                                timeout=60)
            assert answer.status_code == 202, answer.text
        big = still_recording(3000)  # the server takes seconds to parse it

        async def hello() -> dict:
            ws = await connect(srv.ws_url,
                               additional_headers={"Authorization": f"Bearer {token}"})
            await ws.send(json.dumps(HELLO))
            try:
                answer = json.loads(await asyncio.wait_for(ws.recv(), 60))
                if answer["type"] == "ready":
                    await ws.send(json.dumps({"type": "bye"}))
            except ConnectionClosed as exc:
                answer = {"closed": exc.rcvd.code if exc.rcvd else None}
            await ws.close()
            return answer

        upload, answer, took = asyncio.run(_big_upload_then(srv.url, token, big, hello))
        print(f"\n{'postgres' if database_env else 'sqlite'}: the last session of the hour, "
              f"a hello during an upload's parse: hello {answer.get('type')} "
              f"({answer.get('reason', '')[:60]}) in {took * 1000:.0f} ms; upload "
              f"{upload.status_code} {upload.text[:90]}; {stored()} stored, limit {LIMIT}")
        assert stored() <= LIMIT, f"{stored()} sessions in the hour, the limit is {LIMIT}"
        # one of the two got the last place; the other was told the limit, nothing stored
        assert (answer.get("type") == "ready") != (upload.status_code == 202), (answer, upload)
        refused = upload.json()["detail"] if upload.status_code != 202 else answer["reason"]
        assert SETTING in refused and f"= {LIMIT}" in refused, refused
        assert upload.status_code in (202, 429), upload.text
        assert stored() == LIMIT
    finally:
        srv.stop()


def test_one_upload_of_a_kit_at_a_time_across_two_instances(tmp_path, database_env):
    """Two ``armtrack serve`` on one database (PostgreSQL: docs/operator.md "Scaling out";
    SQLite: one file, two processes of one machine): while instance A stores a long upload
    of a kit, the kit's next upload to instance B is told at once that another is being
    stored (429), nothing stored; once A is done B takes it."""
    env = database_env or {"ARMTRACK_DATABASE_URL": f"sqlite:///{tmp_path / 'one.db'}"}
    a = _server(tmp_path / "a", env)
    a.create_user("alice")
    a.start()
    b = _server(tmp_path / "b", env).start()
    try:
        alice = a.client("alice")
        patient = alice.patient("Two instances")
        token = alice.device(patient["id"])["token"]
        kit = {"Authorization": f"Bearer {token}"}
        small = still_recording(5)

        async def to_b() -> httpx.Response:
            async with httpx.AsyncClient(base_url=b.url, timeout=300) as http:
                return await http.post("/api/recordings", headers=kit, data={"wait": "false"},
                                       files={"file": ("small.csv", small)})

        first, second, took = asyncio.run(
            _big_upload_then(a.url, token, still_recording(3000), to_b))
        print(f"\n{'postgres' if database_env else 'sqlite'}: "
              f"an upload to B while A stores one of the same kit: {second.status_code} "
              f"in {took * 1000:.0f} ms: {second.text[:100]}; A's: {first.status_code}")
        assert first.status_code == 202, first.text
        assert second.status_code == 429, second.text
        assert "another upload from this kit is being stored" in second.json()["detail"]
        assert took < 2.0  # answered at once, not after A's upload
        again = httpx.post(f"{b.url}/api/recordings", headers=kit, data={"wait": "false"},
                           files={"file": ("small.csv", small)}, timeout=60)
        assert again.status_code == 202, again.text
        assert a.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",
                     p=patient["id"])[0][0] == 2
    finally:
        b.stop()
        a.stop()


def test_a_hello_waits_for_the_kits_count_turn_a_bounded_time(tmp_path, postgres_url):
    """On PostgreSQL a hello takes the kit's count turn (``new_sessions.count_turn``) while
    an upload of the kit may hold it until its inserts commit (seconds for a large one): a
    hello waits at most ``HELLO_WAIT_S`` in its database thread (the server has 4), then is
    refused as busy (4429 before ready: the kit tries again). The turn is free again once
    the holder commits. Real PostgreSQL, the server's migrations."""
    from armtrack.server.db import models
    from armtrack.server.db.engine import make_engine, make_sessionmaker
    from armtrack.server.db.migrate import upgrade
    from armtrack.server.kit import new_sessions
    from server_support import add_patient

    engine = make_engine(fresh_postgres_database(postgres_url))
    upgrade(engine)
    factory = make_sessionmaker(engine)
    with factory() as db:
        device = models.Device(patient_id=add_patient(db, "p", None).id, name="kit",
                               token_hash="h")
        db.add(device)
        db.commit()
        device_id = device.id
    results: list[tuple[bool, float]] = []
    with factory() as upload, factory() as hello:
        assert new_sessions.count_turn(upload, device_id) is True  # held: not committed

        def take() -> None:
            began = time.monotonic()
            results.append((new_sessions.count_turn(hello, device_id,
                                                    wait_s=new_sessions.HELLO_WAIT_S),
                            time.monotonic() - began))

        import threading
        waiter = threading.Thread(target=take, daemon=True)
        waiter.start()
        waiter.join(new_sessions.HELLO_WAIT_S + 10)
        print(f"\nthe hello's turn while an upload holds it: {results}")
        assert results, "the hello still waits"
        taken, took = results[0]
        assert taken is False and new_sessions.HELLO_WAIT_S - 0.1 <= took \
            <= new_sessions.HELLO_WAIT_S + 2
        upload.commit()
        began = time.monotonic()
        assert new_sessions.count_turn(hello, device_id, wait_s=new_sessions.HELLO_WAIT_S)
        assert time.monotonic() - began < 1.0
        hello.commit()
    engine.dispose()
