"""One test per rule of spec/recording.md: a valid file, broken one way, is refused with the
exact line number and the rule; the vectorised and the line-by-line checks agree."""

from __future__ import annotations

import pytest
from armtrack.estimator.errors import InvalidRecording
from armtrack.estimator.recording import Recording, parse_recording, read_recording, reader
from armtrack.estimator.recording.reader import _parse

VALID = [
    "# armtrack-recording: 1",  # 1
    "# side: right",  # 2
    "# height_m: 1.80",  # 3
    "# calibration: npose 0.5 3.0; tpose 5.5 8.0",  # 4
    "# marks: 12.0 exercise:elbow_flexion; 40.0 end:exercise:elbow_flexion",  # 5
    "# rate_hz: 100",  # 6
    "# scenario: unit",  # 7
    "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz",  # 8
    "0.00,upper_arm,0.112,9.803,-0.241,0.0031,-0.0102,0.0054,21.3,-38.0,12.9",  # 9
    "0.00,forearm,-0.172,9.839,-0.625,0.0069,-0.0053,-0.0028,,,",  # 10
    "0.01,upper_arm,0.113,9.801,-0.240,0.0030,-0.0101,0.0055,21.4,-38.1,12.8",  # 11
    "0.01,forearm,-0.171,9.838,-0.626,0.0070,-0.0054,-0.0027,,,",  # 12
    "0.02,upper_arm,0.114,9.800,-0.239,0.0029,-0.0100,0.0056,21.5,-38.2,12.7",  # 13
    "0.02,forearm,-0.170,9.837,-0.627,0.0071,-0.0055,-0.0026,,,",  # 14
]
COLUMNS = VALID[7].split(",")


def encode(lines: list[str]) -> bytes:
    return ("\n".join(lines) + "\n").encode("utf-8")


def line(n: int, text: str):
    """Replace line n (1-based)."""
    return lambda lines: [*lines[: n - 1], text, *lines[n:]]


def field(n: int, column: str, text: str):
    """Replace one field of line n."""

    def mutate(lines):
        fields = lines[n - 1].split(",")
        fields[COLUMNS.index(column)] = text
        return [*lines[: n - 1], ",".join(fields), *lines[n:]]

    return mutate


def insert(n: int, text: str):
    """Insert a line so that it becomes line n."""
    return lambda lines: [*lines[: n - 1], text, *lines[n - 1 :]]


def delete(n: int):
    return lambda lines: lines[: n - 1] + lines[n:]


def mags(n: int, x: str, y: str, z: str):
    def mutate(lines):
        fields = lines[n - 1].split(",")
        fields[8:11] = [x, y, z]
        return [*lines[: n - 1], ",".join(fields), *lines[n:]]

    return mutate


def raw(transform):
    """A mutation of the file's bytes rather than its lines."""
    return lambda lines: transform(encode(lines))


CASES = [
    # --- the file and its header ---------------------------------------------------------
    ("empty file", raw(lambda b: b""), 1, "empty file"),
    ("version missing", delete(1), 7, "missing required header 'armtrack-recording'"),
    ("version 3", line(1, "# armtrack-recording: 3"), 1,
     "unsupported format version 3 (supported: 1, 2)"),
    ("version 3 reported first", lambda ls: ["# side: up", "# armtrack-recording: 3", *ls[2:]],
     2, "unsupported format version 3 (supported: 1, 2)"),
    ("version not a number", line(1, "# armtrack-recording: one"), 1,
     "armtrack-recording must be a format version (supported: 1, 2), got 'one'"),
    ("side missing", delete(2), 7, "missing required header 'side'"),
    ("side unknown", line(2, "# side: both"), 2, "side must be right or left, got 'both'"),
    ("height and lengths missing", delete(3), 7,
     "missing header 'height_m' or 'lengths_m' (one is required)"),
    ("height not a number", line(3, "# height_m: tall"), 3,
     "height_m is not a plain decimal number ('tall')"),
    ("height with underscore", line(3, "# height_m: 1_80"), 3,
     "height_m is not a plain decimal number ('1_80')"),
    ("height not finite", line(3, "# height_m: inf"), 3, "height_m is not finite ('inf')"),
    ("height implausible", line(3, "# height_m: 18.0"), 3,
     "height_m: body height must be within 0.5–2.6 m, got 18.0"),
    ("lengths incomplete", line(3, "# lengths_m: clavicle=0.23 upper_arm=0.33 forearm=0.26"), 3,
     "lengths_m misses hand (all four are needed)"),
    ("lengths unknown segment",
     line(3, "# lengths_m: clavicle=0.23 upper_arm=0.33 forearm=0.26 foot=0.19"), 3,
     "lengths_m: unknown segment 'foot'"),
    ("lengths twice",
     line(3, "# lengths_m: clavicle=0.23 clavicle=0.23 forearm=0.26 hand=0.19"), 3,
     "lengths_m gives clavicle twice"),
    ("lengths not name=value",
     line(3, "# lengths_m: clavicle 0.23 upper_arm=0.33 forearm=0.26 hand=0.19"), 3,
     "lengths_m entry must be segment=metres, got 'clavicle'"),
    ("lengths negative",
     line(3, "# lengths_m: clavicle=0.23 upper_arm=-0.33 forearm=0.26 hand=0.19"), 3,
     "lengths_m: segment length upper_arm must be a finite length in (0, 1.5) m, got -0.33"),
    ("calibration unknown pose", line(4, "# calibration: apose 0.5 3.0"), 4,
     "calibration pose must be npose or tpose, got 'apose'"),
    ("calibration ends before start", line(4, "# calibration: npose 3.0 0.5"), 4,
     "calibration: npose must start before it ends, got 3.0 to 0.5"),
    ("calibration empty period", line(4, "# calibration: npose 3.0 3.0"), 4,
     "npose must start before it ends"),
    ("calibration not finite", line(4, "# calibration: npose 0.5 nan"), 4,
     "calibration npose end is not finite ('nan')"),
    ("calibration entry shape", line(4, "# calibration: npose 0.5"), 4,
     "calibration entry must be 'NAME START END', got 'npose 0.5'"),
    ("calibration empty entry", line(4, "# calibration: npose 0.5 3.0;"), 4,
     "calibration has an empty entry"),
    ("mark label unknown", line(5, "# marks: 12.0 stretch"), 5,
     "marks: mark label must be npose, tpose, exercise:<name> or end:<label>, got 'stretch'"),
    ("mark label no name", line(5, "# marks: 12.0 exercise:"), 5, "got 'exercise:'"),
    ("mark without time", line(5, "# marks: exercise:elbow_flexion"), 5,
     "marks entry must be 'T LABEL', got 'exercise:elbow_flexion'"),
    ("mark time bad", line(5, "# marks: 1,2 npose"), 5,
     "mark time is not a plain decimal number ('1,2')"),
    ("rate zero", line(6, "# rate_hz: 0"), 6, "rate_hz must be positive, got '0'"),
    ("rate negative", line(6, "# rate_hz: -100"), 6, "rate_hz must be positive"),
    ("duplicate key", insert(4, "# side: left"), 4,
     "duplicate header key 'side' (first on line 2)"),
    ("duplicate metadata key", insert(8, "# scenario: again"), 8,
     "duplicate header key 'scenario' (first on line 7)"),
    ("header line without colon", line(7, "# exported by hand"), 7,
     "header line must be '# key: value', got '# exported by hand'"),
    ("header key with space", line(7, "# my key: value"), 7,
     "header key must be letters, digits, '_', '.', '-', got 'my key'"),
    ("blank line in header", insert(4, ""), 4, "blank line before the column line"),
    ("column line wrong", line(8, "t,sensor,ax,ay,az,gx,gy,gz"), 8,
     "expected the column line 't,sensor,ax,ay,az,gx,gy,gz,mx,my,mz', got"),
    ("column line missing", lambda ls: ls[:7], 8, "missing the column line"),
    ("no data rows", lambda ls: ls[:8], 9, "no data rows after the column line"),
    ("only blank lines after the column line", lambda ls: [*ls[:8], "", ""], 9,
     "no data rows after the column line"),
    ("stray CR in header", raw(lambda b: b.replace(b"# side: right", b"# side:\r right")), 2,
     "stray carriage return"),
    ("header not UTF-8", raw(lambda b: b.replace(b"unit", b"\xff\xfe")), 7, "not valid UTF-8"),
    # --- data rows -------------------------------------------------------------------------
    ("too few fields", line(11, "0.01,upper_arm,0.113,9.801,-0.240,0.0030,-0.0101,0.0055,21.4"),
     11, "expected 11 fields (t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz), got 9"),
    ("too many fields", field(12, "mz", ",,"), 12, "expected 11 fields"),
    ("underscore in number", field(11, "ax", "1_0"), 11,
     "ax is not a plain decimal number ('1_0')"),
    ("space in number", field(11, "ay", " 9.801"), 11,
     "ay is not a plain decimal number (' 9.801')"),
    ("space after number", field(13, "t", "0.02 "), 13,
     "t is not a plain decimal number ('0.02 ')"),
    ("tab in number", field(11, "gz", "\t0.0055"), 11, "gz is not a plain decimal number"),
    ("quoted number", field(11, "az", '"-0.240"'), 11, "az is not a plain decimal number"),
    ("hex number", field(11, "gx", "0x1"), 11, "gx is not a plain decimal number ('0x1')"),
    ("comma decimal", field(11, "gx", "0;003"), 11, "gx is not a plain decimal number ('0;003')"),
    ("inf", field(11, "gy", "inf"), 11, "gy is not finite ('inf')"),
    ("minus infinity", field(11, "t", "-Infinity"), 11, "t is not finite ('-Infinity')"),
    ("nan", field(12, "az", "nan"), 12, "az is not finite ('nan')"),
    ("NaN in mag", field(11, "my", "NaN"), 11, "my is not finite ('NaN')"),
    ("overflow", field(11, "ax", "1e400"), 11, "ax is not finite ('1e400')"),
    ("missing t", field(12, "t", ""), 12, "missing value for t"),
    ("missing ax", field(11, "ax", ""), 11, "missing value for ax"),
    ("missing gz", field(12, "gz", ""), 12, "missing value for gz"),
    ("unknown sensor", field(12, "sensor", "elbow"), 12,
     "unknown sensor 'elbow' (expected one of trunk, clavicle, upper_arm, forearm, hand)"),
    ("empty sensor", field(12, "sensor", ""), 12, "unknown sensor ''"),
    ("sensor in capitals", field(12, "sensor", "Forearm"), 12, "unknown sensor 'Forearm'"),
    ("mag partly empty", mags(11, "21.4", "", "12.8"), 11,
     "mx, my, mz must be all empty (6-axis) or all given"),
    ("mag one given", mags(12, "", "", "12.8"), 12,
     "mx, my, mz must be all empty (6-axis) or all given"),
    ("acceleration beyond range", field(11, "ay", "170"), 11,
     "|a| = 170 m/s² of sensor upper_arm is beyond the physical range (|a| ≤ 160 m/s²)"),
    ("acceleration norm beyond range",
     lambda ls: field(12, "ax", "120")(field(12, "ay", "120")(ls)), 12,
     "|a| = 169.707 m/s² of sensor forearm is beyond the physical range"),
    ("angular rate beyond range", field(13, "gx", "-35.5"), 13,
     "|g| = 35.5 rad/s of sensor upper_arm is beyond the physical range (|g| ≤ 35 rad/s)"),
    ("magnetic field beyond range", mags(11, "3000", "3000", "3000"), 11,
     "|m| = 5196.15 µT of sensor upper_arm is beyond the physical range (|m| ≤ 5000 µT)"),
    ("9-axis sensor loses mag", mags(13, "", "", ""), 13,
     "sensor upper_arm has no magnetometer values here but is 9-axis from line 9"),
    ("6-axis sensor gains mag", mags(14, "20", "-40", "10"), 14,
     "sensor forearm has magnetometer values here but is 6-axis from line 10"),
    ("t backwards", field(13, "t", "0.005"), 13,
     "t goes backwards for sensor upper_arm (0.005 after 0.01)"),
    ("blank line in data", insert(12, ""), 12,
     "blank line (blank lines are allowed only at the end)"),
    ("header line after column line", insert(10, "# note: late"), 10,
     "header line after the column line"),
    ("stray CR in data", raw(lambda b: b.replace(b"0.0054,21.3", b"0.0054\r,21.3")), 9,
     "stray carriage return (lines end with LF or CRLF)"),
    ("bare CR line end", raw(lambda b: b.replace(b"12.8\n", b"12.8\r")), 11,
     "stray carriage return"),
    ("data not UTF-8", raw(lambda b: b.replace(b"0.02,forearm", b"0.02,fore\xe9rm")), 14,
     "not valid UTF-8"),
    ("BOM before the first data row", insert(9, "\ufeff0.00,hand,0,9.81,0,0,0,0,,,"), 9,
     "t is not a plain decimal number ('\\ufeff0.00')"),
    ("non-ASCII digit", field(11, "ax", "١"), 11, "ax is not a plain decimal number ('١')"),
]


def _case_ids():
    return [c[0] for c in CASES]


@pytest.mark.parametrize(("name", "mutate", "line_no", "rule"), CASES, ids=_case_ids())
def test_broken_file_is_refused_naming_line_and_rule(name, mutate, line_no, rule):
    out = mutate(list(VALID))
    data = out if isinstance(out, bytes) else encode(out)
    with pytest.raises(InvalidRecording) as fast:
        parse_recording(data)
    assert fast.value.line == line_no, str(fast.value)
    assert str(fast.value).startswith(f"line {line_no}: "), str(fast.value)
    assert rule in str(fast.value)
    with pytest.raises(InvalidRecording) as slow:
        _parse(data, fast=False)
    assert str(slow.value) == str(fast.value)


def test_the_valid_file_reads():
    rec = parse_recording(encode(VALID))
    assert list(rec.sensors) == ["upper_arm", "forearm"]
    assert rec.sensors["upper_arm"].nine_axis and not rec.sensors["forearm"].nine_axis
    assert rec.sensors["forearm"].mag is None
    assert rec.sensors["forearm"].acc[1].tolist() == [-0.171, 9.838, -0.626]
    assert [m.label for m in rec.marks] == ["exercise:elbow_flexion", "end:exercise:elbow_flexion"]
    assert rec.metadata == {"scenario": "unit"} and rec.rate_hz == 100.0


def test_spec_example_error_message_deep_in_a_file():
    """The spec's own example: line 812, t going backwards for the forearm."""
    rows = [
        f"{12.35 - (802 - k) * 0.01:.2f},forearm,0.1,9.8,0.2,0.01,0.02,0.03,20,-40,10"
        for k in range(803)
    ]
    lines = [*VALID[:8], *rows, "12.34,forearm,0.1,9.8,0.2,0.01,0.02,0.03,20,-40,10"]
    assert lines[810].startswith("12.35,") and len(lines) == 812
    with pytest.raises(InvalidRecording) as exc:
        parse_recording(encode(lines))
    assert str(exc.value) == "line 812: t goes backwards for sensor forearm (12.34 after 12.35)"


ALLOWED = [
    ("CRLF line ends", raw(lambda b: b.replace(b"\n", b"\r\n"))),
    ("mixed line ends", raw(lambda b: b.replace(b"12.8\n", b"12.8\r\n"))),
    ("UTF-8 byte order mark", raw(lambda b: b"\xef\xbb\xbf" + b)),
    ("trailing blank lines", raw(lambda b: b + b"\n\r\n\n")),
    ("no final line end", raw(lambda b: b.rstrip(b"\n"))),
    ("plus sign, exponent, bare point", lambda ls: field(11, "ax", "+1.13e-1")(
        field(11, "az", "-.240")(field(11, "gx", "3.e-3")(ls)))),
    ("equal times for one sensor", field(13, "t", "0.01")),
    ("lengths instead of height",
     line(3, "# lengths_m: hand=0.19 clavicle=0.23 upper_arm=0.33 forearm=0.26")),
    ("both height and lengths",
     insert(4, "# lengths_m: clavicle=0.23 upper_arm=0.33 forearm=0.26 hand=0.19")),
    ("no optional headers", lambda ls: [ls[0], ls[1], ls[2], *ls[7:]]),
    ("loose header spacing", line(2, "#side:right  ")),
    ("metadata with colons and unicode", line(7, "# note: 12:00 Zürich; ok")),
    ("empty metadata value", line(7, "# note:")),
    ("a trunk and a hand",
     lambda ls: [*ls, "0.03,trunk,0,9.81,0,0,0,0,1,2,3", "0,hand,0,0,0,0,0,0,,,"]),
    ("exactly at the physical limits", lambda ls: mags(11, "0", "-5000", "0")(
        field(11, "ax", "0")(field(11, "ay", "160")(field(11, "az", "0")(
            field(11, "gx", "0")(field(11, "gy", "-35")(field(11, "gz", "0")(ls)))))))),
    ("one tpose only, repeated marks", lambda ls: line(5, "# marks: 1 npose; 2 end:npose; 3 npose")(
        line(4, "# calibration: tpose 5.5 8.0")(ls))),
]


@pytest.mark.parametrize(("name", "mutate"), ALLOWED, ids=[a[0] for a in ALLOWED])
def test_allowed_variations_read(name, mutate):
    out = mutate(list(VALID))
    data = out if isinstance(out, bytes) else encode(out)
    rec = parse_recording(data)
    assert isinstance(rec, Recording)
    slow = _parse(data, fast=False)
    for sensor, stream in rec.sensors.items():
        other = slow.sensors[sensor]
        assert stream.t.tobytes() == other.t.tobytes()
        assert stream.acc.tobytes() == other.acc.tobytes()
        assert stream.nine_axis == other.nine_axis


def test_segment_lengths_prefer_measured_over_height():
    both = insert(4, "# lengths_m: clavicle=0.23 upper_arm=0.33 forearm=0.26 hand=0.19")(VALID)
    rec = parse_recording(encode(both))
    assert rec.height_m == 1.8 and rec.segment_lengths().upper_arm == 0.33
    assert parse_recording(encode(VALID)).segment_lengths().upper_arm == pytest.approx(0.186 * 1.8)


def test_line_numbers_count_from_the_first_line_even_with_a_bom():
    data = b"\xef\xbb\xbf" + encode(field(12, "sensor", "elbow")(VALID))
    with pytest.raises(InvalidRecording, match=r"^line 12: unknown sensor 'elbow'"):
        parse_recording(data)


def test_reading_a_broken_file_returns_nothing(tmp_path):
    path = tmp_path / "broken.csv"
    path.write_bytes(encode(field(13, "t", "0.005")(VALID)))
    result = None
    with pytest.raises(InvalidRecording, match="line 13: t goes backwards"):
        result = read_recording(path)
    assert result is None


def test_errors_deep_in_a_multi_block_file():
    """Line numbers stay exact across Arrow's blocks (4 MiB) on both paths."""
    n = 150_000
    t = [k * 0.01 for k in range(n)]
    rows = [f"{x!r},hand,0.5,9.7,-0.25,0.001,0.002,-0.003,20.5,-40.25,10.125" for x in t]
    lines = [*VALID[:8], *rows]
    assert len(encode(lines)) > 2 * (4 << 20)
    assert len(parse_recording(encode(lines)).sensors["hand"]) == n
    back = list(lines)
    back[100_000] = back[100_000].replace(repr(t[100_000 - 8]), "1.5", 1)
    with pytest.raises(InvalidRecording) as exc:
        parse_recording(encode(back))
    assert str(exc.value) == (
        f"line 100001: t goes backwards for sensor hand (1.5 after {t[100_000 - 9]!r})"
    )
    spaced = list(lines)
    spaced[110_000] = spaced[110_000].replace(",hand,", ", hand,")
    with pytest.raises(InvalidRecording, match=r"^line 110001: unknown sensor ' hand'"):
        parse_recording(encode(spaced))


def _long_file(n: int = 150_000) -> list[str]:
    """A valid file of n rows (over 10 MiB): upper_arm 9-axis and forearm 6-axis
    alternating, with a single trunk row at line 9 (t = 5.0)."""
    rows = ["5.0,trunk,0,9.81,0,0,0,0,1,2,3"]
    for k in range(n - 1):
        t = (k // 2) * 0.01
        if k % 2:
            rows.append(f"{t!r},forearm,0.5,9.7,-0.25,0.001,0.002,-0.003,,,")
        else:
            rows.append(f"{t!r},upper_arm,0.5,9.7,-0.25,0.001,0.002,-0.003,20.5,-40.25,10.125")
    return [*VALID[:8], *rows]


def _refused(lines: list[str], data_line: int, rule: str) -> None:
    data = encode(lines)
    with pytest.raises(InvalidRecording) as fast:
        parse_recording(data)
    assert str(fast.value).startswith(f"line {data_line}: {rule}"), str(fast.value)
    with pytest.raises(InvalidRecording) as slow:
        _parse(data, fast=False)
    assert str(slow.value) == str(fast.value)


def test_an_error_arrow_refuses_is_located_in_its_piece():
    lines = _long_file()
    lines[140_000 - 1] = lines[140_000 - 1].replace(",0.5,", ",x.5,")
    _refused(lines, 140_000, "ax is not a plain decimal number ('x.5')")


def test_an_earlier_error_wins_over_the_piece_arrow_refuses():
    lines = _long_file()
    lines[140_000 - 1] = lines[140_000 - 1].replace(",0.5,", ",x.5,")
    lines[30_001 - 1] = lines[30_001 - 1].replace(",9.7,", ",197,")
    _refused(lines, 30_001, "|a| = 197.001 m/s² of sensor")


def test_the_line_by_line_pass_starts_from_the_earlier_pieces_state():
    lines = _long_file()
    lines[130_000 - 1] = "1.0,trunk,0,9.81,0,0,0,0,1,2,3"
    lines[130_010 - 1] = lines[130_010 - 1].replace(",0.5,", ", 0.5,")  # Arrow refuses
    _refused(lines, 130_000, "t goes backwards for sensor trunk (1.0 after 5.0)")
    lines[130_000 - 1] = "6.0,trunk,0,9.81,0,0,0,0,,,"
    _refused(lines, 130_000,
             "sensor trunk has no magnetometer values here but is 9-axis from line 9")


def test_a_valid_piece_arrow_refuses_is_read_line_by_line(monkeypatch):
    """Should Arrow refuse valid text (none is known), that piece goes through the
    line-by-line pass and the rest through Arrow, with the same numbers."""
    lines = _long_file(50_000)
    lines[20_001] = lines[20_001].replace(",0.5,", ",0.50000000000000000000000000000001,")
    data = encode(lines)
    expected = parse_recording(data)
    marked = data.index(lines[20_001].encode())
    real_fast, real_slow = reader._parse_fast, reader.parse_rows_slow
    slow_lines = []

    def fast(data, begin, end):
        return None if begin <= marked < end else real_fast(data, begin, end)

    def slow(lines, first_line, checker=None):
        slow_lines.append((first_line, len(lines)))
        return real_slow(lines, first_line, checker)

    monkeypatch.setattr(reader, "_parse_fast", fast)
    monkeypatch.setattr(reader, "parse_rows_slow", slow)
    got = parse_recording(data)
    assert len(slow_lines) == 1 and 0 < slow_lines[0][1] < 30_000, slow_lines
    assert slow_lines[0][0] <= 20_002 < slow_lines[0][0] + slow_lines[0][1]
    for name, stream in expected.sensors.items():
        for q in ("t", "acc", "gyr"):
            assert getattr(got.sensors[name], q).tobytes() == getattr(stream, q).tobytes()
    assert got.sensors["upper_arm"].acc[:, 0].max() == 0.5
