"""End to end: a real server process, the kit emulator streaming the shared recordings
over the ingest protocol, the data read back over REST. On SQLite and, when the tests
have one (``ARMTRACK_TEST_POSTGRES_URL``), on PostgreSQL. One server per database for the
module (``module_server``): each test adds patients of its own and reads only theirs."""

import asyncio

import numpy as np
import pytest
from armtrack.estimator.recording import parse_recording, read_recording
from armtrack.server.cli import main as armtrack_main
from armtrack.server.emulator import KitEmulator

pytestmark = pytest.mark.both_databases

SHARED = ["elbow_flexion", "shoulder_abduction", "shoulder_flexion", "wrist_flexion",
          "pronation", "left_reach_50hz", "elbow_6axis", "elbow_6axis_long", "trunk_reach",
          "abduction_120"]


def stream(server, token, recording, **kwargs):
    kit = KitEmulator(recording, server.ws_url, token, speed=0, **kwargs)
    return asyncio.run(kit.run())


def assert_same_samples(stored, original):
    assert list(stored.sensors) == list(original.sensors)
    for name, s in original.sensors.items():
        got = stored.sensors[name]
        for column in ("t", "acc", "gyr", "mag"):
            a, b = getattr(got, column), getattr(s, column)
            if b is None:
                assert a is None
                continue
            # bit-identical: the same float64 values, compared as integers
            assert np.array_equal(a.view(np.int64), b.view(np.int64)), (name, column)
    assert stored.calibration == original.calibration
    assert stored.marks == original.marks


def test_streamed_recordings_are_stored_exactly_and_estimated_as_the_cli_does(
        module_server, recordings_dir, tmp_path):
    server = module_server
    api = server.client("alice")
    for name in SHARED:
        path = recordings_dir / f"{name}.csv"
        recording = read_recording(path)
        patient = api.patient(name, recording.side, recording.height_m or 1.75)
        token = api.device(patient["id"])["token"]
        stats = stream(server, token, recording)
        assert stats.acked == stats.total and not stats.errors, (name, stats.errors)

        session = api.wait_processed(stats.session)
        assert session["status"] == "closed" and session["processing_error"] is None
        assert session["samples"] == sum(len(s) for s in recording.sensors.values())
        assert session["estimator"]["filter"] == "qcf"

        exported = api.http.get(f"/api/sessions/{stats.session}/recording.csv")
        assert exported.status_code == 200
        assert_same_samples(parse_recording(exported.content), recording)

        # the stored estimates are those `armtrack estimate` gives on the same file
        cli_out = tmp_path / f"{name}.angles.csv"
        assert armtrack_main(["estimate", str(path), "-o", str(cli_out)]) == 0
        stored = api.http.get(f"/api/sessions/{stats.session}/angles.csv")
        assert stored.status_code == 200
        assert stored.text == cli_out.read_text(), name
        print(f"{name}: {session['samples']} samples in {stats.total} messages, "
              f"ack p99 {1000 * stats.latency_percentiles((99,))[99]:.1f} ms, identical")


def test_uploaded_recording_becomes_a_processed_session(module_server, recordings_dir):
    server = module_server
    api = server.client("alice")
    patient = api.patient()
    path = recordings_dir / "elbow_6axis.csv"
    with open(path, "rb") as f:
        answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                               files={"file": ("elbow_6axis.csv", f, "text/csv")})
    assert answer.status_code == 201, answer.text
    session = answer.json()
    assert session["source"] == "upload" and session["processed"]
    assert session["calibration"]["method"] in ("two-pose", "n-pose")
    exported = api.http.get(f"/api/sessions/{session['id']}/recording.csv")
    assert_same_samples(parse_recording(exported.content), read_recording(path))


@pytest.mark.parametrize("bad", [b"not a recording", b"# armtrack-recording: 1\n"])
def test_a_bad_upload_is_refused_whole(module_server, bad):
    server = module_server
    api = server.client("alice")
    patient = api.patient()
    answer = api.http.post("/api/recordings", data={"patient_id": patient["id"]},
                           files={"file": ("bad.csv", bad, "text/csv")})
    assert answer.status_code == 422
    assert "line" in answer.json()["detail"]
    assert api.http.get(f"/api/patients/{patient['id']}/sessions").json() == []
