"""Work whose size depends on time stamps is bounded by the data's size (issue 17, item 3),
and equal time stamps (packed samples, allowed by ``spec/recording.md``) are handled
everywhere (issue 18): the metrics' time base, ``armtrack estimate``, ``armtrack check``,
and a real server's reports, PDF and patient export.

The attack: a valid recording whose upper-arm stream has a sample every 0.2 s, each
followed by a near-duplicate 1 µs (or 10 ns) later. The median interval then says
"1 MHz" (or "100 MHz") and a report resampled whole stretches on that grid: 20 s and
4.4 GB for one ``GET /report``, or a 500 ("Unable to allocate 29.7 GiB") on every report
and on the patient's export until the session was erased."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from armtrack.estimator.metrics import timebase
from armtrack.estimator.recording import SensorStream, write_recording
from armtrack.estimator.sampling import summarise_sampling
from armtrack.estimator.simulation import SimulationConfig, simulate
from server_support import ServerProcess, armtrack

RATE_HZ = 50.0


# -- the time base, alone --------------------------------------------------------------

def test_equal_stamps_are_a_series_and_collapse_before_any_rate():
    t = np.repeat(np.arange(50) * 0.02, 2)  # packed in pairs: 100 samples, 50 stamps
    x = np.sin(t)
    t2, _ = timebase.as_series(t, x)
    assert t2.shape == (100,)
    u, v = timebase.collapse_equal(t, x)
    assert u.shape == (50,) and np.all(np.diff(u) > 0)
    np.testing.assert_allclose(v, np.sin(u))
    grid, values, rate = timebase.uniform(t, x)
    # 100 samples over 0.98 s: the packed stream's sample rate is ~100 Hz, not 50 or 0
    assert 95.0 <= rate <= 105.0, rate
    np.testing.assert_allclose(values, np.sin(grid), atol=1e-3)


def test_time_going_backwards_names_plain_numbers():
    with pytest.raises(Exception) as caught:
        timebase.as_series(np.array([0.0, 0.8243, 0.8, 1.0]), np.zeros(4))
    message = str(caught.value)
    assert "np.float64" not in message and "0.8243" in message and "0.8" in message


@pytest.mark.parametrize("offset_s", [1e-6, 1e-8, 0.0])
def test_a_grid_is_bounded_by_the_data(offset_s):
    base = np.arange(0, 600, 0.2)  # 10 minutes at 5 Hz
    t = np.sort(np.concatenate([base, base + offset_s, base + 2 * offset_s]))
    x = np.cos(t)
    start = time.perf_counter()
    grid, _, rate = timebase.uniform(t, x)
    elapsed = time.perf_counter() - start
    print(f"offset {offset_s:g} s: {t.size} samples → grid of {grid.size} at {rate:.3g} Hz "
          f"in {elapsed * 1000:.1f} ms")
    assert grid.size <= timebase.GRID_FACTOR * t.size + 1
    assert elapsed < 1.0


def test_a_given_rate_is_capped_too():
    t = np.arange(0, 10, 0.01)
    grid, _, rate = timebase.uniform(t, np.zeros_like(t), rate_hz=1e9)  # a lying header
    assert grid.size <= timebase.GRID_FACTOR * t.size + 1
    assert rate <= timebase.GRID_FACTOR * 100.0 + 1e-6


def test_normal_data_keeps_its_median_rate():
    rng = np.random.default_rng(3)
    t = np.arange(0, 60, 0.01) + rng.normal(0, 0.0005, 6000)
    t = np.sort(t)
    keep = rng.random(t.size) > 0.05  # 5 % lost
    _, _, rate = timebase.uniform(t[keep], np.zeros(keep.sum()))
    assert rate == pytest.approx(timebase.median_rate_hz(t[keep]))
    assert rate == pytest.approx(100.0, rel=0.02)


# -- sampling summaries (armtrack check, reports' quality) ----------------------------

def test_packed_samples_are_not_lost():
    """Every second sample re-stamped with its predecessor's time: nothing is lost and
    the rate is the samples' rate (was 0.0 Hz and 33 % lost)."""
    t = np.arange(0, 20, 0.01)
    t[1::2] = t[:-1:2]
    summary = summarise_sampling(t, 100.0)
    assert summary.rate_hz == pytest.approx(100.0, rel=0.01)
    assert summary.lost == 0
    alone = summarise_sampling(t)  # no nominal rate: the same
    assert alone.rate_hz == pytest.approx(100.0, rel=0.01)
    assert alone.lost == 0


def test_packed_samples_with_a_real_gap():
    t = np.repeat(np.arange(0, 10, 0.04), 4)  # packets of 4 at 100 Hz
    t = t[(t < 4.0) | (t >= 5.0)]  # one second lost
    summary = summarise_sampling(t, 100.0)
    assert summary.lost == pytest.approx(100, abs=4)
    assert summary.rate_hz == pytest.approx(100.0, rel=0.01)


# -- recordings with such stamps -------------------------------------------------------

def simulated(tmp_path: Path, name: str, restamp) -> Path:
    """A simulated 50 Hz elbow session whose upper-arm stream is ``restamp(stream)``."""
    result = simulate(SimulationConfig(exercise="elbow_flexion", rate_hz=RATE_HZ, seed=1,
                                       repetitions=4))
    recording = result.recording
    sensors = dict(recording.sensors)
    sensors["upper_arm"] = restamp(recording.sensors["upper_arm"])
    path = tmp_path / name
    write_recording(replace(recording, sensors=sensors), path)
    return path


def packed(stream: SensorStream) -> SensorStream:
    """Every second sample stamped with its predecessor's time (packets of two)."""
    t = stream.t.copy()
    t[1::2] = t[:-1:2]
    return SensorStream(t=t, acc=stream.acc, gyr=stream.gyr, mag=stream.mag)


def near_duplicates(offset_s: float):
    """The first half as it was; then, after a gap of 0.3 s, a sample every 0.2 s, each
    followed by a copy ``offset_s`` later. The first half sets the median interval of the
    whole (so the arm's range of motion counts as moved); the second half is a stretch of
    its own whose median interval is ``offset_s``."""
    def restamp(stream: SensorStream) -> SensorStream:
        half = len(stream) // 2
        pairs = np.repeat(np.arange(half + int(0.3 * RATE_HZ), len(stream),
                                    int(0.2 * RATE_HZ)), 2)
        keep = np.concatenate([np.arange(half), pairs])
        t = stream.t[keep]
        t[half:] += np.tile([0.0, offset_s], pairs.size // 2)
        return SensorStream(t=t, acc=stream.acc[keep], gyr=stream.gyr[keep],
                            mag=None if stream.mag is None else stream.mag[keep])
    return restamp


def test_estimate_handles_equal_stamps(tmp_path):
    path = simulated(tmp_path, "packed.csv", packed)
    out = tmp_path / "angles.csv"
    done = armtrack("estimate", str(path), "-o", str(out))
    print(done.stdout, done.stderr)
    assert done.returncode == 0, done.stderr
    assert out.is_file() and out.stat().st_size > 0
    assert "np.float64" not in done.stdout + done.stderr


def test_check_reports_packed_samples(tmp_path):
    path = simulated(tmp_path, "packed.csv", packed)
    done = armtrack("check", str(path), "--json")
    assert done.returncode == 0, done.stderr
    arm = json.loads(done.stdout)["sensors"]["upper_arm"]
    print(arm)
    assert arm["rate_hz"] == pytest.approx(RATE_HZ, rel=0.01)
    assert arm["lost_samples"] == 0 and arm["lost_percent"] == 0.0


# -- a real server --------------------------------------------------------------------

def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    server = ServerProcess(tmp_path_factory.mktemp("timebase"))
    server.create_user("alice")
    server.start(timeout=120)
    yield server
    server.stop()


def upload(api, patient_id: int, path: Path) -> dict:
    with open(path, "rb") as f:
        answer = api.http.post("/api/recordings", data={"patient_id": patient_id},
                               files={"file": (path.name, f)})
    assert answer.status_code == 201, answer.text
    return answer.json()


@pytest.mark.parametrize("name,restamp", [
    ("dup-1us.csv", near_duplicates(1e-6)),
    ("dup-10ns.csv", near_duplicates(1e-8)),
    ("packed.csv", packed),
], ids=["1us", "10ns", "equal"])
def test_reports_stay_small_and_fast(srv, tmp_path, name, restamp):
    api = srv.client("alice")
    patient = api.patient(name=f"Timebase {name}")
    session = upload(api, patient["id"], simulated(tmp_path, name, restamp))
    session = api.wait_processed(session["id"])
    assert session["processed"], session
    before = peak_rss_mb(srv.process.pid)
    for route in (f"/api/sessions/{session['id']}/report",
                  f"/api/sessions/{session['id']}/report.pdf",
                  f"/api/sessions/{session['id']}/report.csv",
                  f"/api/sessions/{session['id']}/report.sto",
                  f"/api/sessions/{session['id']}/summary",
                  f"/api/patients/{patient['id']}/summaries",
                  f"/api/patients/{patient['id']}/progress",
                  f"/api/patients/{patient['id']}/export"):
        start = time.perf_counter()
        answer = api.http.get(route)
        elapsed = time.perf_counter() - start
        print(f"{name} {route}: {answer.status_code} in {elapsed:.2f} s")
        assert answer.status_code == 200, (route, answer.text[:300])
        assert elapsed < 10.0, (route, elapsed)
    grown = peak_rss_mb(srv.process.pid) - before
    print(f"{name}: the server's peak memory grew {grown:.0f} MB")
    assert grown < 300, grown
    report = api.http.get(f"/api/sessions/{session['id']}/report").json()
    arm = next(s for s in report["quality"]["sensors"] if s["name"] == "upper_arm")
    if name == "packed.csv":
        assert arm["lost_samples"] == 0
        assert arm["rate_hz"] == pytest.approx(RATE_HZ, rel=0.02)
