"""Imported vendor files cost the server memory in proportion to what they are allowed to
hold, on a real server: a small file that declares or unpacks to far more than an upload
may hold is refused (413) naming the file, before it is read, and the server's peak memory
does not grow by the declared size. A kit's token may upload, so a patient's phone (or
whoever holds its link) is the hostile caller here."""

from __future__ import annotations

import io
import json
import time

import pytest
from server_support import ServerProcess

#: the test server's upload limit (ARMTRACK_MAX_UPLOAD_BYTES)
LIMIT = 8 << 20


@pytest.fixture(scope="module")
def small_limit_server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("server"),
                            {"ARMTRACK_MAX_UPLOAD_BYTES": str(LIMIT)})
    process.create_user("alice")
    process.start()
    yield process
    process.stop()


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
    assert elapsed < 5
    assert server.sql("SELECT COUNT(*) FROM sessions WHERE patient_id = :p",
                      p=patient["id"])[0][0] == 0
