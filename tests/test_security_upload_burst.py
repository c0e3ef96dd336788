"""Security review (Low): one kit could tie up the server's worker threads. A kit's uploads
are counted and stored one at a time (``ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR``), and each
waiting upload held a threadpool thread while it waited for the one being stored: a burst
of 40 from one kit token filled the pool and every other therapist's request stalled until
they drained. Now an upload that finds another of its kit being stored is answered at once
(429, "another upload from this kit is being stored; send this one when it is done"),
nothing stored; other therapists keep being answered. Real server, real database file,
real HTTP clients."""

from __future__ import annotations

import asyncio
import time

import httpx
import numpy as np
import pytest
from server_support import ServerProcess

LIMIT = 3
BURST = 45  # more than the server's worker threads (AnyIO's default: 40)


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("upload_burst"), env={
        "ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR": str(LIMIT)})
    server.create_user("alice")
    server.create_user("bob")
    server.start()
    yield server
    server.stop()


SENSORS = ("upper_arm", "forearm", "hand")


def still_recording(seconds: int, rate_hz: int = 100) -> bytes:
    """A 6-axis recording of a still arm, three sensors (docs/spec/recording.md); each
    second's noise is the same."""
    rng = np.random.default_rng(0)
    second = "".join(
        f"{{s}}.{i:02d},{sensor},{ax:.4f},{ay + 9.81:.4f},{az:.4f},{gx:.5f},{gy:.5f},{gz:.5f},,,\n"
        for i in range(rate_hz) for sensor in SENSORS
        for ax, ay, az, gx, gy, gz in [rng.normal(0.0, 0.05, 6) * [1, 1, 1, 0.2, 0.2, 0.2]])
    rows = "".join(second.format(s=s) for s in range(seconds))
    return ("# armtrack-recording: 1\n# side: right\n# height_m: 1.75\n"
            f"# rate_hz: {rate_hz}\nt,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n{rows}").encode()


def test_a_burst_of_one_kits_uploads_does_not_stall_other_users(srv):
    alice = srv.client("alice")
    patient = alice.patient("Burst")
    token = alice.device(patient["id"])["token"]
    bob = srv.client("bob")
    bob.patient("Elsewhere")
    big = still_recording(3000)  # takes the server a few seconds to parse and store
    small = still_recording(5)
    stored = lambda: srv.sql("SELECT count(*) FROM sessions WHERE patient_id = :p",  # noqa: E731
                             p=patient["id"])[0][0]
    kit = {"Authorization": f"Bearer {token}"}

    async def scenario():
        limits = httpx.Limits(max_connections=BURST + 10, max_keepalive_connections=0)
        async with httpx.AsyncClient(base_url=srv.url, limits=limits, timeout=180) as http:
            async def upload(data: bytes, name: str) -> httpx.Response:
                return await http.post("/api/recordings", headers=kit, data={"wait": "false"},
                                       files={"file": (name, data)})

            # the first upload's body, sent in pieces: the burst follows its last piece
            request = http.build_request("POST", "/api/recordings", headers=kit,
                                         data={"wait": "false"},
                                         files={"file": ("long.csv", big)})
            body, sent = request.read(), asyncio.Event()

            async def pieces():
                for at in range(0, len(body), 1 << 20):
                    yield body[at:at + (1 << 20)]
                sent.set()

            first = asyncio.create_task(http.post(
                "/api/recordings", content=pieces(), headers={
                    **kit, "Content-Type": request.headers["Content-Type"],
                    "Content-Length": str(len(body))}))
            await sent.wait()
            await asyncio.sleep(0.2)  # the server parses and stores it
            burst = [asyncio.create_task(upload(small, f"burst{i}.csv"))
                     for i in range(BURST)]
            waits = []  # bob's plain requests meanwhile [s]
            async with httpx.AsyncClient(base_url=srv.url, headers=bob.http.headers,
                                         timeout=180) as other:
                while not (first.done() and all(task.done() for task in burst)):
                    began = time.monotonic()
                    answer = await other.get("/api/patients")
                    assert answer.status_code == 200, answer.text
                    waits.append(time.monotonic() - began)
                    await asyncio.sleep(0.05)
            return await first, [await task for task in burst], waits

    first, answers, waits = asyncio.run(scenario())
    codes = [answer.status_code for answer in answers]
    busy = [answer for answer in answers if answer.status_code == 429
            and "another upload from this kit is being stored" in answer.json()["detail"]]
    print(f"\nfirst upload {first.status_code}; burst of {BURST}: "
          f"{ {code: codes.count(code) for code in set(codes)} }, {len(busy)} told another "
          f"is being stored; bob's {len(waits)} requests meanwhile: median "
          f"{np.median(waits) * 1000:.0f} ms, longest {max(waits) * 1000:.0f} ms")
    if busy:
        print(busy[0].json()["detail"])
    assert first.status_code == 202, first.text
    assert max(waits) < 1.0, f"another therapist waited {max(waits):.1f} s"
    assert len(busy) >= BURST // 2, codes  # the burst came while the first was stored
    assert all(code in (202, 429) for code in codes), codes
    assert "send this one when it is done" in busy[0].json()["detail"]
    assert stored() <= LIMIT  # never more than the hourly limit
    # the kit sends it again once the one before is done: taken
    if stored() < LIMIT:
        again = httpx.post(f"{srv.url}/api/recordings", headers=kit, data={"wait": "false"},
                           files={"file": ("again.csv", small)}, timeout=60)
        assert again.status_code == 202, again.text
    assert stored() <= LIMIT
