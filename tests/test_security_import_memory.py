"""Imported vendor files cost the server memory in proportion to what they are allowed to
hold, on a real server: a small file that declares or unpacks to far more than an upload
may hold is refused (413) naming the file, before it is read, and the server's peak memory
does not grow by the declared size. A kit's token may upload, so a patient's phone (or
whoever holds its link) is the hostile caller here."""

from __future__ import annotations

import io
import json
import time

import httpx
import pytest
from server_support import ServerProcess, server_fixture

#: the test server's upload limit (ARMTRACK_MAX_UPLOAD_BYTES)
LIMIT = 8 << 20


small_limit_server = server_fixture("server", "alice",
                                    env={"ARMTRACK_MAX_UPLOAD_BYTES": str(LIMIT)})


def peak_rss_mb(pid: int) -> float:
    """The process's peak resident memory so far (VmHWM) [MiB]."""
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


def apdm_declaring(samples: int) -> bytes:
    """An APDM-like .h5 of one sensor whose datasets declare ``samples`` rows but hold
    no data (chunked, never written: the file is a few kB; reading it fills them)."""
    h5py = pytest.importorskip("h5py")
    buf = io.BytesIO()
    with h5py.File(buf, "w") as f:
        group = f.create_group("Sensors/1234")
        group.create_dataset("Time", shape=(samples,), dtype="u8", chunks=(4096,))
        for name in ("Accelerometer", "Gyroscope"):
            group.create_dataset(name, shape=(samples, 3), dtype="f4", chunks=(4096, 3))
    return buf.getvalue()


@pytest.mark.parametrize("route", ["/api/recordings/inspect", "/api/recordings"])
def test_an_hdf5_declaring_huge_datasets_is_refused_before_it_is_read(small_limit_server,
                                                                      route):
    """A 4 kB .h5 declaring 20 million samples per dataset (640 MB as stored, 1.1 GB as
    float64) took 13 s and 1.4 GB of the server's memory (a kit's token is enough; 2³²
    samples would have exhausted the machine's memory)."""
    server = small_limit_server
    alice = server.client("alice")
    patient = alice.patient(f"H5 {route[-7:]}")
    kit = alice.device(patient["id"], "phone")
    data = apdm_declaring(20_000_000)
    before = peak_rss_mb(server.process.pid)
    start = time.monotonic()
    answer = alice.http.post(route, headers={"Authorization": f"Bearer {kit['token']}"},
                             data={"sensors": json.dumps({"forearm": "bomb.h5:1234"})},
                             files=[("files", ("bomb.h5", data, "application/octet-stream"))],
                             timeout=300)
    elapsed = time.monotonic() - start
    grown = peak_rss_mb(server.process.pid) - before
    print(f"{len(data)} bytes: {answer.status_code} in {elapsed:.2f} s, peak memory "
          f"+{grown:.0f} MiB: {answer.text[:300]}")
    assert answer.status_code == 413, answer.text  # as an upload over the limit
    detail = answer.json()["detail"]
    assert "bomb.h5" in detail and str(LIMIT) in detail, detail
    assert grown < 100, f"the server's peak memory grew by {grown:.0f} MiB"
    assert elapsed < 20  # the .h5 reader's own process starts in 1-4 s on a busy machine
    assert server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                      p=patient["id"])[0][0] == 0


@pytest.fixture
def fresh_server(tmp_path):
    """A server of its own, so its peak memory is this test's."""
    process = ServerProcess(tmp_path / "server", {"ARMTRACK_MAX_UPLOAD_BYTES": str(LIMIT)})
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


DOT_HEADER = ("sep=,\nDeviceTag:,D1\nSyncStatus:,Synced\nOutputRate:,60Hz\n\n"
              "PacketCounter,SampleTimeFine,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z\n")
GENERIC_HEADER = "t,ax,ay,az,gx,gy,gz\n"


def hostile_csv(kind: str, header: str, size: int) -> bytes:
    """About ``size`` bytes of CSV that Arrow's fast reader refuses, so the reader falls
    back to its line-by-line check: ``short`` millions of 3-byte lines; ``bad_tail``
    plausible rows with a word in the last; ``wide`` a header of millions of columns."""
    if kind == "short":
        return (header + "1,1,1,1,1,1,1,1\n" + "10\n" * (size // 3)).encode()
    if kind == "bad_tail":
        row = "10,10,10,10,10,10,10,10\n"
        return (header + row * (size // len(row)) + "1,x,1,1,1,1,1,1\n").encode()
    return (header.rstrip("\n") + ",a" * (size // 2) + "\n1,1,1,1,1,1,1,1\n").encode()


@pytest.mark.parametrize("kind", ["short", "bad_tail", "wide"])
@pytest.mark.parametrize("route", ["/api/recordings/inspect", "/api/recordings"])
def test_a_hostile_csv_costs_the_server_little_memory(fresh_server, route, kind):
    """7.5 MB of CSV under the 8 MiB limit: 3-byte lines cost the server +600 MiB (80x
    the file, 9-13 s; one 200 MiB upload at the default limit would take ~16 GB), a
    damaged last row +235 MiB (31x: every row split into lists at once); a 3.75 M-cell
    header +22 MiB but 2.5-4.3 s. Refused naming the file, with the server's peak memory
    grown by less than 15x the file."""
    server = fresh_server
    alice = server.client("alice")
    patient = alice.patient("Csv")
    kit = alice.device(patient["id"], "phone")
    size = 7_500_000
    if route.endswith("inspect"):  # the format is found from the header
        data, form = hostile_csv(kind, DOT_HEADER, size), {}
    else:
        data = hostile_csv(kind, GENERIC_HEADER.replace("\n", ",x\n"), size)
        form = {"sensors": json.dumps({"forearm": "rows.csv"}), "format": "generic",
                "options": json.dumps({"columns": "t=t ax=ax ay=ay az=az gx=gx gy=gy gz=gz"})}
    before = peak_rss_mb(server.process.pid)
    start = time.monotonic()
    answer = alice.http.post(route, headers={"Authorization": f"Bearer {kit['token']}"},
                             data=form, files=[("files", ("rows.csv", data, "text/csv"))],
                             timeout=300)
    elapsed = time.monotonic() - start
    grown = peak_rss_mb(server.process.pid) - before
    print(f"{kind} {route}: {len(data)} bytes, {answer.status_code} in {elapsed:.2f} s, "
          f"peak memory +{grown:.0f} MiB: {answer.text[:240]}")
    if route.endswith("inspect"):  # a file it cannot read is named in the answer
        assert answer.status_code == 200, answer.text
        (found,) = answer.json()["files"]
        assert found["error"] and "rows.csv" in found["error"] and not found["sensors"], found
    else:
        assert answer.status_code == 422, answer.text
        assert "rows.csv" in answer.json()["detail"]
        assert server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                          p=patient["id"])[0][0] == 0
    assert grown < 15 * len(data) / 2**20, f"peak memory grew by {grown:.0f} MiB"


def apdm_reading(path: str, samples: int, *, how: str) -> bytes:
    """An APDM-like .h5 whose Accelerometer is not in the file: ``external`` raw storage
    in the file at ``path`` on the reading machine, an external ``link`` to, or a
    ``virtual`` dataset mapping, an HDF5 file there."""
    h5py = pytest.importorskip("h5py")
    import numpy as np

    buf = io.BytesIO()
    with h5py.File(buf, "w") as f:
        group = f.create_group("Sensors/77")
        group.create_dataset("Time", data=np.arange(samples, dtype="u8") * 20_000)
        group.create_dataset("Gyroscope", data=np.zeros((samples, 3), "f4"))
        if how == "external":
            group.create_dataset("Accelerometer", shape=(samples, 3), dtype="f4",
                                 external=[(path, 0, samples * 12)])
        elif how == "link":
            group["Accelerometer"] = h5py.ExternalLink(path, "/acc")
        else:
            layout = h5py.VirtualLayout(shape=(samples, 3), dtype="f4")
            layout[:] = h5py.VirtualSource(path, "acc", shape=(samples, 3))
            group.create_virtual_dataset("Accelerometer", layout)
    return buf.getvalue()


@pytest.mark.parametrize("how", ["external", "link", "virtual"])
def test_an_hdf5_cannot_make_the_server_read_its_own_files(small_limit_server, tmp_path, how):
    """HDF5 lets a dataset's data live in another file, named by path: reading the
    upload read that file of the server's disk (its database, keys …) as the sensor's
    samples, which the therapist could then export as the recording. Refused naming the
    dataset, nothing stored."""
    import numpy as np

    server = small_limit_server
    alice = server.client("alice")
    patient = alice.patient(f"H5 outside {how}")
    samples = 500
    secret = np.tile(np.array([0.123456, 9.81, 0.654321], "f4"), (samples, 1))
    target = tmp_path / ("secret.bin" if how == "external" else "secret.h5")
    if how == "external":
        target.write_bytes(secret.tobytes())
    else:
        import h5py
        with h5py.File(target, "w") as f:
            f.create_dataset("acc", data=secret)
    data = apdm_reading(str(target), samples, how=how)
    answer = alice.http.post("/api/recordings", data={
        "patient_id": str(patient["id"]), "sensors": json.dumps({"forearm": "in.h5:77"}),
        "calibration": "npose 0 2; tpose 4 6"},
        files=[("files", ("in.h5", data, "application/octet-stream"))])
    leaked = None
    if answer.status_code == 201:
        exported = alice.http.get(f"/api/sessions/{answer.json()['id']}/recording.csv").text
        leaked = "0.123456" in exported
    print(f"{how}: {answer.status_code} {answer.text[:200]}; the export holds the server's "
          f"file: {leaked}")
    assert answer.status_code == 422, answer.text
    assert "in.h5" in answer.json()["detail"] and "Accelerometer" in answer.json()["detail"]
    assert server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                      p=patient["id"])[0][0] == 0


FIXTURES = __import__("pathlib").Path(__file__).parent / "fixtures" / "hostile"


@pytest.mark.parametrize("route", ["/api/recordings/inspect", "/api/recordings"])
def test_an_hdf5_that_crashes_libhdf5_does_not_take_the_server_down(small_limit_server,
                                                                    route):
    """A valid APDM-like .h5 with a few bytes changed (found by fuzzing h5py 3.16: random
    byte changes, one in ~300 files) makes libhdf5 dereference a bad pointer: reading it in
    the server's process killed the server (SIGSEGV: every kit's stream and therapist's
    page with it), on a kit's token. The file is read in a process of its own: refused
    naming the file, the server answering on."""
    server = small_limit_server
    alice = server.client("alice")
    patient = alice.patient(f"H5 crash {route[-7:]}")
    kit = alice.device(patient["id"], "phone")
    data = (FIXTURES / "apdm_crashes_libhdf5.h5").read_bytes()
    try:
        answer = alice.http.post(route, headers={"Authorization": f"Bearer {kit['token']}"},
                                 data={"sensors": json.dumps({"forearm": "bad.h5:1"})},
                                 files=[("files", ("bad.h5", data, "application/x-hdf5"))])
        outcome = f"{answer.status_code} {answer.text[:200]}"
    except httpx.HTTPError as exc:
        answer, outcome = None, f"no answer ({type(exc).__name__})"
    print(f"{route}: {outcome}; server exit code {server.process.poll()}")
    assert server.process.poll() is None, "the server died"
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200
    assert answer is not None
    if route.endswith("inspect"):
        (found,) = answer.json()["files"]
        assert "bad.h5" in (found["error"] or ""), found
    else:
        assert answer.status_code == 422 and "bad.h5" in answer.json()["detail"], answer.text
