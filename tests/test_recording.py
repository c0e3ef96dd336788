"""Recording files: write → read gives the same float64, the shared recordings read as their
README describes, numbers equal Python's float() of their text, the writer's layout and
its refusals."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from armtrack.estimator.body import SENSOR_NAMES, SegmentLengths
from armtrack.estimator.errors import InvalidArgument, InvalidRecording, InvalidShape
from armtrack.estimator.recording import (
    Mark,
    Pose,
    Recording,
    SensorStream,
    check_recording,
    format_recording,
    parse_recording,
    read_recording,
    write_recording,
)
from armtrack.estimator.recording.rules import STEP_LIMIT_S, T_LIMIT_S
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from recording_sets import SHARED_FACTS

# ---------------------------------------------------------------------------------------
# strategies


def _from_bits(bits: int) -> float:
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


def component(bound: float) -> st.SearchStrategy[float]:
    """Any float64 with |x| ≤ bound: hypothesis' floats (subnormals, ±0, edges) and raw
    random bit patterns."""
    bits = st.integers(0, 2**64 - 1).map(_from_bits).filter(
        lambda x: math.isfinite(x) and abs(x) <= bound
    )
    return st.one_of(st.floats(-bound, bound, allow_subnormal=True), bits)


# Per-component bounds keep every 3-vector within the physical range (bound·√3 < limit).
BOUNDS = {"acc": 92.0, "gyr": 20.0, "mag": 2886.0}
# Times within the bounds of docs/extensions/time-bounds.md: a start anywhere (so far that
# n steps stay inside), then steps of 0 (ties) up to half the longest step allowed.
starts = st.one_of(component(T_LIMIT_S - 12 * STEP_LIMIT_S),
                   st.sampled_from([0.0, 0.01, 0.02, 1.5]))  # ties across sensors
steps = st.one_of(st.sampled_from([0.0, 0.01]), component(STEP_LIMIT_S / 2).map(abs))


@st.composite
def streams(draw, n_max: int = 12) -> SensorStream:
    n = draw(st.integers(1, n_max))
    t = draw(starts) + np.concatenate(([0.0], np.cumsum(
        draw(arrays(np.float64, n - 1, elements=steps)))))
    acc = draw(arrays(np.float64, (n, 3), elements=component(BOUNDS["acc"])))
    gyr = draw(arrays(np.float64, (n, 3), elements=component(BOUNDS["gyr"])))
    mag = draw(st.none() | arrays(np.float64, (n, 3), elements=component(BOUNDS["mag"])))
    return SensorStream(t, acc, gyr, mag)


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=True)


@st.composite
def poses(draw) -> Pose:
    start = draw(finite)
    end = draw(finite.filter(lambda e: e > start))
    return Pose(draw(st.sampled_from(["npose", "tpose"])), start, end)


labels = st.from_regex(r"\A(end:)?(npose|tpose|exercise:[a-z0-9_.\-]{1,12})\Z")
meta_keys = st.from_regex(r"\A[A-Za-z0-9_][A-Za-z0-9_.\-]{0,10}\Z").filter(
    lambda k: k not in ("armtrack-recording", "side", "height_m", "lengths_m", "calibration",
                        "marks", "rate_hz")
)
# Text a header line can carry: one line, encodable as UTF-8 (no lone surrogates; their
# refusal is tested on its own below).
meta_values = st.text(st.characters(codec="utf-8", exclude_characters="\n\r"),
                      max_size=20).map(str.strip)


@st.composite
def recordings(draw) -> Recording:
    names = draw(st.lists(st.sampled_from(SENSOR_NAMES), min_size=1, max_size=5, unique=True))
    lengths = draw(st.none() | st.builds(
        SegmentLengths, *[st.floats(1e-3, 1.4)] * 4))
    height = draw(st.floats(0.5, 2.6)) if lengths is None else draw(st.none() | st.floats(0.5, 2.6))
    return Recording(
        side=draw(st.sampled_from(["right", "left"])),
        sensors={name: draw(streams()) for name in names},
        height_m=height,
        lengths=lengths,
        calibration=tuple(draw(st.lists(poses(), max_size=3))),
        marks=tuple(draw(st.lists(st.builds(Mark, finite, labels), max_size=3))),
        rate_hz=draw(st.none() | st.floats(1e-3, 1e4)),
        metadata=draw(st.dictionaries(meta_keys, meta_values, max_size=3)),
    )


def same_bits(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.dtype == b.dtype == np.float64 and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same(a: Recording, b: Recording) -> None:
    assert list(a.sensors) == list(b.sensors)
    for name in a.sensors:
        sa, sb = a.sensors[name], b.sensors[name]
        for q in ("t", "acc", "gyr", "mag"):
            assert same_bits(getattr(sa, q), getattr(sb, q)), (name, q)
    assert (a.side, a.height_m, a.lengths, a.rate_hz) == (b.side, b.height_m, b.lengths, b.rate_hz)
    assert (a.calibration, a.marks, a.metadata) == (b.calibration, b.marks, b.metadata)


# ---------------------------------------------------------------------------------------
# round trip


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(recordings())
def test_write_then_read_gives_identical_float64(rec):
    data = format_recording(rec)
    assert_same(rec, parse_recording(data))


def test_round_trip_through_a_file_many_rows_multi_block(tmp_path):
    """A recording big enough for several Arrow blocks, 6- and 9-axis, rows interleaved."""
    rng = np.random.default_rng(7)
    sensors = {}
    for k, name in enumerate(("trunk", "upper_arm", "forearm", "hand")):
        n = 60_000 + 1000 * k
        t = np.cumsum(rng.exponential(0.01, n)) - 0.5
        t[100:110] = t[100]  # ties within a sensor
        mag = None if name == "forearm" else rng.normal(0, 30, (n, 3))
        sensors[name] = SensorStream(t, rng.normal(0, 5, (n, 3)), rng.normal(0, 1, (n, 3)), mag)
    rec = Recording("left", sensors, height_m=1.7, rate_hz=100.0)
    path = tmp_path / "big.csv"
    write_recording(rec, path)
    assert path.stat().st_size > 3 * (4 << 20)
    back = read_recording(path)
    assert_same(rec, back)
    assert_same(back, read_recording(str(path)))
    assert_same(back, read_recording(path.read_bytes()))


def test_six_axis_only_round_trip():
    t = np.array([0.0, 0.01])
    rec = Recording("right", {"hand": SensorStream(t, np.ones((2, 3)), np.zeros((2, 3)))},
                    height_m=1.8)
    data = format_recording(rec)
    assert data.splitlines()[-1] == b"0.01,hand,1,1,1,0,0,0,,,"
    assert parse_recording(data).sensors["hand"].mag is None


# ---------------------------------------------------------------------------------------
# the writer's layout


def test_writer_layout_header_order_and_merged_rows():
    one = np.ones((2, 3))
    rec = Recording(
        side="left",
        sensors={  # given out of order: kept in SENSOR_NAMES order
            "hand": SensorStream([0.0, 0.02], one * 0.5, one * 0.25, None),
            "upper_arm": SensorStream([0.0, 0.01], one, one * 0.1, one * 20),
        },
        height_m=1.7,
        lengths=SegmentLengths(0.23, 0.33, 0.26, 0.19),
        calibration=(Pose("npose", 0.5, 3.0), Pose("tpose", 5.5, 8)),
        marks=(Mark(12, "exercise:elbow_flexion"), Mark(40.0, "end:exercise:elbow_flexion")),
        rate_hz=50,
        metadata={"scenario": "x", "empty": ""},
    )
    assert list(rec.sensors) == ["upper_arm", "hand"]
    assert format_recording(rec).decode().splitlines() == [
        "# armtrack-recording: 1",
        "# side: left",
        "# height_m: 1.7",
        "# lengths_m: clavicle=0.23 upper_arm=0.33 forearm=0.26 hand=0.19",
        "# calibration: npose 0.5 3.0; tpose 5.5 8.0",
        "# marks: 12.0 exercise:elbow_flexion; 40.0 end:exercise:elbow_flexion",
        "# rate_hz: 50.0",
        "# scenario: x",
        "# empty:",
        "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz",
        "0,upper_arm,1,1,1,0.1,0.1,0.1,20,20,20",  # tie at 0: SENSOR_NAMES order
        "0,hand,0.5,0.5,0.5,0.25,0.25,0.25,,,",
        "0.01,upper_arm,1,1,1,0.1,0.1,0.1,20,20,20",
        "0.02,hand,0.5,0.5,0.5,0.25,0.25,0.25,,,",
    ]


def test_writer_keeps_a_sensors_equal_times_in_order():
    acc = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    rec = Recording("right", {"forearm": SensorStream([1.0, 1.0, 1.0], acc, np.zeros((3, 3)))},
                    height_m=1.8)
    back = parse_recording(format_recording(rec))
    assert back.sensors["forearm"].acc[:, 0].tolist() == [1.0, 2.0, 3.0]


def _bad(**change) -> Recording:
    t = np.array([0.0, 0.01, 0.02])
    acc, gyr, mag = np.zeros((3, 3)), np.zeros((3, 3)), np.full((3, 3), 20.0)
    parts = {"t": t, "acc": acc, "gyr": gyr, "mag": mag} | change
    return Recording("right", {"forearm": SensorStream(**parts)}, height_m=1.8)


REFUSED = [
    ("t backwards", _bad(t=np.array([0.0, 0.02, 0.01])),
     "sample 2: t goes backwards for sensor forearm (0.01 after 0.02)"),
    ("nan in gyr", _bad(gyr=np.array([[0, 0, 0], [0, np.nan, 0], [0, 0, 0]])),
     "sensor forearm, sample 1: gyr is not finite"),
    ("inf t", _bad(t=np.array([0.0, 1.0, np.inf])), "sensor forearm, sample 2: t is not finite"),
    ("acc beyond range", _bad(acc=np.array([[0, 0, 0], [0, 0, 0], [0, 0, 161.0]])),
     "sample 2: |a| = 161 m/s² of sensor forearm is beyond the physical range"),
    ("huge mag", _bad(mag=np.full((3, 3), 1e200)), "sample 0: |m| = 1.73205e+200 µT"),
    ("no samples", _bad(t=np.empty(0), acc=np.empty((0, 3)), gyr=np.empty((0, 3)),
                        mag=np.empty((0, 3))), "sensor forearm has no samples"),
]


@pytest.mark.parametrize(("name", "rec", "message"), REFUSED, ids=[r[0] for r in REFUSED])
def test_writer_refuses_before_writing_anything(tmp_path, name, rec, message):
    path = tmp_path / "out.csv"
    path.write_bytes(b"old content")
    with pytest.raises(InvalidRecording) as exc:
        write_recording(rec, path)
    assert message in str(exc.value)
    with pytest.raises(InvalidRecording):
        format_recording(rec)
    assert path.read_bytes() == b"old content"
    assert os.listdir(tmp_path) == ["out.csv"]


def test_writer_refuses_metadata_changed_after_construction():
    rec = _bad()
    rec.metadata["two\nlines"] = "x"
    with pytest.raises(InvalidRecording, match="metadata key"):
        check_recording(rec)


def test_write_is_atomic_when_the_rename_fails(tmp_path, monkeypatch):
    path = tmp_path / "out.csv"
    path.write_bytes(b"old content")

    def crash(src, dst):
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="disk gone"):
        write_recording(_bad(), path)
    assert path.read_bytes() == b"old content"
    assert os.listdir(tmp_path) == ["out.csv"]


def test_written_file_is_owner_only_whatever_the_umask(tmp_path):
    """A recording is a patient's data: 0600 (issue 24: it followed the umask, 0644)."""
    for umask in (0o022, 0o000):
        old = os.umask(umask)
        try:
            write_recording(_bad(), tmp_path / "out.csv")
        finally:
            os.umask(old)
        assert (tmp_path / "out.csv").stat().st_mode & 0o777 == 0o600


# ---------------------------------------------------------------------------------------
# the data classes


def test_streams_are_read_only_float64_with_checked_shapes():
    s = SensorStream([0, 1], [[0, 0, 9.81], [0, 0, 9.81]], np.zeros((2, 3), np.float32))
    assert s.t.dtype == s.gyr.dtype == np.float64 and not s.nine_axis and len(s) == 2
    with pytest.raises(ValueError, match="read-only"):
        s.acc[0, 0] = 1.0
    with pytest.raises(InvalidShape, match=r"acc must have shape \(N, 3\), got \(2, 2\)"):
        SensorStream([0, 1], np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(InvalidShape, match="gyr must have 2 rows like t, got 3"):
        SensorStream([0, 1], np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(InvalidShape, match=r"t must have shape \(N,\)"):
        SensorStream(np.zeros((2, 1)), np.zeros((2, 3)), np.zeros((2, 3)))


def test_recording_checks_its_structure():
    s = SensorStream([0.0], np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InvalidArgument, match="side"):
        Recording("middle", {"hand": s}, height_m=1.8)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="unknown sensor 'elbow'"):
        Recording("right", {"elbow": s}, height_m=1.8)
    with pytest.raises(InvalidArgument, match="height_m or lengths"):
        Recording("right", {"hand": s})
    with pytest.raises(InvalidArgument, match="body height"):
        Recording("right", {"hand": s}, height_m=18.0)
    with pytest.raises(InvalidArgument, match="header field of its own"):
        Recording("right", {"hand": s}, height_m=1.8, metadata={"side": "left"})
    with pytest.raises(InvalidArgument, match="without surrounding spaces"):
        Recording("right", {"hand": s}, height_m=1.8, metadata={"note": " x"})
    with pytest.raises(InvalidArgument, match="note is not encodable as UTF-8"):
        Recording("right", {"hand": s}, height_m=1.8, metadata={"note": "a\ud800"})
    with pytest.raises(InvalidArgument, match="start before it ends"):
        Pose("npose", 3.0, 1.0)
    with pytest.raises(InvalidArgument, match="mark label"):
        Mark(1.0, "exercise: curls")
    rec = Recording("right", {"hand": s}, height_m=1.8)
    assert rec.version == 1 and rec.duration == 0.0 and rec.calibration == ()


def test_duration_spans_all_sensors():
    z = np.zeros((2, 3))
    rec = Recording("right", {"hand": SensorStream([1.0, 5.0], z, z),
                              "trunk": SensorStream([-0.5, 4.0], z, z)}, height_m=1.8)
    assert rec.duration == 5.5


# ---------------------------------------------------------------------------------------
# the shared recordings


def test_every_shared_recording_reads_and_is_described(recordings_dir):
    files = sorted(p for p in recordings_dir.glob("*.csv")
                   if not p.name.endswith(".truth.csv"))
    assert files, "no recordings in shared/data/recordings"
    for path in files:
        rec = read_recording(path)
        assert rec.sensors, path.name
        assert path.stem in SHARED_FACTS, (
            f"{path.name} is new: add it to tests/recording_sets.py with its README facts")


@pytest.mark.parametrize("name", sorted(SHARED_FACTS))
def test_recording_matches_its_readme(recording_set, name):
    """Each set's files against the shared README (side, height, rate, axes, sensors,
    calibration windows: the stand-ins are the same sessions) and against what is known
    of that set's file: the README's length, losses and jitter for the shared files, the
    simulation's for the stand-ins (tests/recording_sets.py)."""
    readme = SHARED_FACTS[name]
    facts = recording_set.facts[name]
    rec = read_recording(recording_set.path(name))
    assert (rec.side, rec.height_m, rec.rate_hz) == (readme.side, readme.height_m,
                                                      readme.rate_hz)
    assert tuple(rec.sensors) == readme.sensors
    assert all(s.nine_axis == readme.nine_axis for s in rec.sensors.values())
    assert rec.calibration == (Pose("npose", 0.5, 3.0), Pose("tpose", 5.5, 8.0))
    assert rec.metadata["scenario"] == facts.scenario
    if recording_set.source == "shared":
        assert rec.metadata == {"scenario": name}
    assert rec.duration == pytest.approx(facts.duration_s, abs=0.01)
    rate = readme.rate_hz
    print(f"{recording_set.source} {name}: {rec.duration:.2f} s, "
          f"{[len(s) for s in rec.sensors.values()]} samples")
    for sensor, s in rec.sensors.items():
        dt = np.median(np.diff(s.t))
        assert dt == pytest.approx(1.0 / rate, rel=0.01 if facts.jitter_std_s else 1e-6), sensor
        expected = round(facts.duration_s * rate) + 1
        if facts.lost_fraction:  # 2% samples lost
            assert 0.95 * expected < len(s) < expected, sensor
        else:
            assert len(s) == expected, sensor
        if facts.jitter_std_s:  # 1 ms of jitter
            jitter = np.std(s.t - np.round(s.t * rate) / rate)
            assert jitter == pytest.approx(facts.jitter_std_s, rel=0.1), (
                f"{sensor}: jitter {jitter:.2e} s")
        g = np.linalg.norm(s.acc[: int(rate)], axis=1).mean()  # first second: at rest
        assert g == pytest.approx(9.81, abs=0.2), f"{name} {sensor}: |a| at rest {g:.3f}"
        assert not np.isnan(s.acc).any() and not np.isnan(s.gyr).any()


@pytest.mark.parametrize("name", ["elbow_flexion", "elbow_6axis", "abduction_120"])
def test_shared_numbers_equal_python_float_of_their_text(recordings_dir, name):
    """Every number of the file, against float() of its text, bit for bit."""
    path = recordings_dir / f"{name}.csv"
    rec = read_recording(path)
    expected: dict[str, list[list[float]]] = {}
    for text in path.read_text().splitlines():
        if text.startswith(("#", "t,")):
            continue
        fields = text.split(",")
        expected.setdefault(fields[1], []).append(
            [float(f) if f else math.nan for f in fields[:1] + fields[2:]]
        )
    for sensor, rows in expected.items():
        s = rec.sensors[sensor]
        mag = s.mag if s.mag is not None else np.full((len(s), 3), np.nan)
        got = np.column_stack([s.t, s.acc, s.gyr, mag])
        assert got.tobytes() == np.array(rows).tobytes(), sensor
    # a few by hand, as written in the file
    if name == "elbow_flexion" and rec.metadata == {"scenario": name}:  # the shared file
        first = rec.sensors["forearm"]
        assert first.acc[0].tolist() == [float("-0.1720"), float("9.8394"), float("-0.6257")]
        assert first.mag[0].tolist() == [float("22.797"), float("-41.296"), float("12.093")]


def test_reading_equals_parsing(recordings_dir, tmp_path):
    path = recordings_dir / "trunk_reach.csv"
    assert_same(read_recording(path), parse_recording(path.read_bytes()))
    assert_same(read_recording(path), read_recording(str(path)))
    assert_same(read_recording(path), read_recording(memoryview(path.read_bytes())))


def test_shared_recording_rewrites_to_the_same_numbers(recordings_dir, tmp_path):
    path = recordings_dir / "left_reach_50hz.csv"
    rec = read_recording(path)
    write_recording(rec, tmp_path / "copy.csv")
    assert_same(rec, read_recording(tmp_path / "copy.csv"))
