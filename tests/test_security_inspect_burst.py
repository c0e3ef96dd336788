"""One kit token's inspections of uploads (``POST /api/recordings/inspect``, which a kit's
token may call: nothing is stored) cost the server one inspection's memory at a time, on
a real server. Each reads its files whole into memory on a worker thread; uploads of a
kit were already stored one at a time (test_security_upload_burst), its inspections not:
12 inspections of a 37 MB recording sent at once by one kit token took the server from
0.57 to 1.19 GB (at the 200 MB upload limit, 40 at once would be tens of GB) and another
therapist's plain request to 1.4 s. Now one arriving while another of the kit is read is
answered 429 at once, saying so; other therapists keep being answered."""

from __future__ import annotations

import asyncio
import time

import httpx
import numpy as np
import pytest
from server_support import server_fixture
from test_security_upload_burst import still_recording

BURST = 12
server = server_fixture("inspect_burst", "alice", "bob")


def peak_rss_mb(pid: int) -> float:
    """The process's peak resident memory so far (VmHWM) [MiB]."""
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


def burst_beside_another(server, headers: dict, other_headers: dict, send):
    """``BURST`` requests ``send(http)`` at once (an httpx.AsyncClient with ``headers``)
    while another therapist (``other_headers``) asks for their patients every 50 ms:
    the burst's answers and the other's waits [s]."""
    async def scenario():
        limits = httpx.Limits(max_connections=BURST + 5, max_keepalive_connections=0)
        async with httpx.AsyncClient(base_url=server.url, limits=limits, timeout=300,
                                     headers=headers) as http:
            burst = [asyncio.create_task(send(http)) for _ in range(BURST)]
            waits = []
            async with httpx.AsyncClient(base_url=server.url, headers=other_headers,
                                         timeout=300) as other:
                while not all(task.done() for task in burst):
                    began = time.monotonic()
                    assert (await other.get("/api/patients")).status_code == 200
                    waits.append(time.monotonic() - began)
                    await asyncio.sleep(0.05)
            return [await task for task in burst], waits

    return asyncio.run(scenario())


def test_a_burst_of_one_kits_inspections_is_read_one_at_a_time(server):
    alice = server.client("alice")
    patient = alice.patient("Inspects")
    kit = {"Authorization": f"Bearer {alice.device(patient['id'])['token']}"}
    bob = server.client("bob")
    data = still_recording(1500)  # 450,000 rows, ~27 MB
    files = {"files": ("session.csv", data, "text/csv")}
    one = httpx.post(f"{server.url}/api/recordings/inspect", headers=kit, files=files,
                     timeout=120)
    assert one.status_code == 200, one.text  # one alone is read (and sets the peak)
    before = peak_rss_mb(server.process.pid)

    answers, waits = burst_beside_another(
        server, kit, bob.http.headers,
        lambda http: http.post("/api/recordings/inspect", files=files))
    grown = peak_rss_mb(server.process.pid) - before
    codes = [a.status_code for a in answers]
    busy = [a for a in answers if a.status_code == 429]
    print(f"\n{BURST} inspections of {len(data) / 1e6:.0f} MB at once from one kit: "
          f"{ {c: codes.count(c) for c in set(codes)} }; the server's peak memory "
          f"+{grown:.0f} MiB over one inspection's; bob's {len(waits)} requests: median "
          f"{np.median(waits) * 1000:.0f} ms, longest {max(waits) * 1000:.0f} ms")
    assert set(codes) <= {200, 429}, codes
    assert busy and all("another inspection from this kit is being read"
                        in a.json()["detail"] for a in busy), busy[:1]
    assert grown < 150, f"the server's peak memory grew {grown:.0f} MiB"
    assert max(waits) < 1.0, f"another therapist waited {max(waits):.1f} s"


@pytest.mark.parametrize("route", ["inspect", "upload"])
def test_a_burst_of_one_therapists_files_is_read_two_at_a_time(server, route):
    """attack13: a therapist's token had no such bound (only a kit's): 12 inspections of a
    30 MB recording at once from one therapist took the server +776 MB and another
    therapist's page to 1.0 s (at the 200 MB upload limit and 40 worker threads: tens of
    GB), 12 uploads +676 MB. Now a therapist's uploads and inspections are read at most
    two at once (two tabs); the next is 429 at once, saying so."""
    alice = server.client("alice")
    patient = alice.patient(f"Therapist's {route}")
    bob = server.client("bob")
    data = still_recording(1500)  # 450,000 rows, ~27 MB
    path = "/api/recordings/inspect" if route == "inspect" else "/api/recordings"
    form = {"patient_id": str(patient["id"])} | ({"wait": "false"} if route == "upload" else {})
    field = "files" if route == "inspect" else "file"
    one = alice.http.post(path, data=form, files={field: ("session.csv", data, "text/csv")},
                          timeout=300)
    assert one.status_code in (200, 202), one.text  # one alone is read (sets the peak)
    before = peak_rss_mb(server.process.pid)

    answers, waits = burst_beside_another(
        server, alice.http.headers, bob.http.headers,
        lambda http: http.post(path, data=form, files={
            field: ("session.csv", data, "text/csv")}))
    grown = peak_rss_mb(server.process.pid) - before
    codes = [a.status_code for a in answers]
    busy = [a for a in answers if a.status_code == 429]
    print(f"\n{BURST} {route}s of {len(data) / 1e6:.0f} MB at once from one therapist: "
          f"{ {c: codes.count(c) for c in set(codes)} }; the server's peak memory "
          f"+{grown:.0f} MiB over one's; bob's {len(waits)} requests: median "
          f"{np.median(waits) * 1000:.0f} ms, longest {max(waits) * 1000:.0f} ms")
    assert set(codes) <= {200, 202, 429}, codes
    assert busy and all("at once" in a.json()["detail"] for a in busy), busy[:1]
    assert grown < 300, f"the server's peak memory grew {grown:.0f} MiB"
