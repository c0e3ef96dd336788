"""The same numbers: the fast reader's float parsing (pyarrow) equals Python's float() of the
text, correctly rounded, on random bit patterns, long decimal strings and exact halfway
cases; the fast and line-by-line paths accept the same number grammar; random damage to a
valid file is refused cleanly, never with another exception."""

from __future__ import annotations

import math
import random
import struct
from decimal import Decimal, localcontext

import numpy as np
import pytest
from armtrack.estimator.errors import InvalidRecording
from armtrack.estimator.recording import Recording
from armtrack.estimator.recording import reader as reader_module
from armtrack.estimator.recording.reader import _parse
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

HEADER = (
    "# armtrack-recording: 1\n# side: right\n# height_m: 1.80\n"
    "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
)


def _from_bits(bits: int) -> float:
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


def texts_of(x: float) -> list[str]:
    """Ways to write x, and the exact decimals halfway to its neighbours (and just past
    them): the cases a parser that is not correctly rounded gets wrong."""
    out = [repr(x), f"{x:.17e}", f"{x:.25e}", f"{x:.40g}", f"{x:.6e}", f"{x:.15g}"]
    with localcontext() as ctx:
        ctx.prec = 1200
        for neighbour in (math.nextafter(x, math.inf), math.nextafter(x, -math.inf)):
            if math.isfinite(neighbour):
                mid = (Decimal(x) + Decimal(neighbour)) / 2  # exact
                out += [format(mid, "e"), format(mid.next_plus(), "e"),
                        format(mid.next_minus(), "e")]
        if 1e-7 < abs(x) < 1e22:
            out.append(format(Decimal(x), "f"))  # the exact value, positional
    return out


def parse_t_column(texts: list[str]) -> np.ndarray:
    """Parse texts as the t column of one sensor through the fast path (ordered by value,
    since t may not go backwards)."""
    texts = sorted(texts, key=float)
    body = "".join(f"{s},hand,0,9.81,0,0,0,0,,,\n" for s in texts)
    # the fast path's parse of the column, before the rules (the time bounds of
    # docs/extensions/time-bounds.md refuse most of these values as times)
    data = (HEADER + body).encode()
    rows = reader_module._parse_fast(data, len(HEADER.encode()), len(data))
    assert rows is not None
    return rows.values[0], np.array([float(s) for s in texts])


@pytest.fixture
def fast_path_only(monkeypatch):
    """Fail the test if the reader falls back to the line-by-line pass."""

    def refuse(*args, **kwargs):
        raise AssertionError("the fast path fell back to the line-by-line pass")

    monkeypatch.setattr(reader_module, "parse_rows_slow", refuse)


def test_arrow_parses_like_python_on_random_bit_patterns(fast_path_only):
    rng = random.Random(20240611)
    texts = []
    while len(texts) < 100_000:
        x = _from_bits(rng.getrandbits(64))
        if math.isfinite(x):
            texts += [s for s in texts_of(x) if math.isfinite(float(s))]
    got, expected = parse_t_column(texts)
    assert got.tobytes() == expected.tobytes()


finite_bits = st.integers(0, 2**64 - 1).map(_from_bits).filter(math.isfinite)
long_decimals = st.from_regex(
    r"\A-?[0-9]{1,40}(\.[0-9]{0,80})?([eE][+-]?[0-9]{1,3})?\Z"
).filter(lambda s: math.isfinite(float(s)))


@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.lists(st.one_of(finite_bits, st.floats(allow_nan=False, allow_infinity=False)),
                min_size=1, max_size=50),
       st.lists(long_decimals, max_size=50))
@example([5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, -0.0, 0.1], ["9" * 400])
def test_arrow_parses_like_python_hypothesis(fast_path_only, values, decimals):
    texts = [s for x in values for s in texts_of(x)] + decimals
    got, expected = parse_t_column([s for s in texts if math.isfinite(float(s))])
    assert got.tobytes() == expected.tobytes()


def outcome(data: bytes, fast: bool):
    """What reading gives: the error message, or every stream's bytes."""
    try:
        rec = _parse(data, fast=fast)
    except InvalidRecording as exc:
        return str(exc)
    assert isinstance(rec, Recording)
    return {name: (s.t.tobytes(), s.acc.tobytes(), s.gyr.tobytes(),
                   None if s.mag is None else s.mag.tobytes()) for name, s in rec.sensors.items()}


number_like = st.text(st.sampled_from("0123456789+-.eE_ \tinfatyINFATY,x\"'"), max_size=8)


@settings(max_examples=500, deadline=None)
@given(number_like, st.sampled_from([0, 2, 3, 5, 8, 9]))
@example("+1.5e1", 2)
@example(" 1", 3)
@example("1e400", 0)
@example("Infinity", 8)
def test_fast_and_line_by_line_accept_the_same_numbers(text, column):
    fields = "0.5,forearm,0.1,9.8,0.2,0.01,0.02,0.03,20,-40,10".split(",")
    fields[column] = text
    data = (HEADER + "0,forearm,0,9.81,0,0,0,0,20,-40,10\n" + ",".join(fields) + "\n").encode()
    assert outcome(data, fast=True) == outcome(data, fast=False)


VALID = (
    b"# armtrack-recording: 1\n# side: left\n# height_m: 1.70\n"
    b"# calibration: npose 0.5 3.0; tpose 5.5 8.0\n# marks: 12.0 exercise:reach\n"
    b"# rate_hz: 50\n# scenario: fuzz\n"
    b"t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
    b"0.00,upper_arm,0.112,9.803,-0.241,0.0031,-0.0102,0.0054,21.3,-38.0,12.9\n"
    b"0.00,forearm,-0.172,9.839,-0.625,0.0069,-0.0053,-0.0028,,,\n"
    b"0.02,upper_arm,0.113,9.801,-0.240,0.0030,-0.0101,0.0055,21.4,-38.1,12.8\n"
    b"0.02,forearm,-0.171,9.838,-0.626,0.0070,-0.0054,-0.0027,,,\n"
    b"0.04,hand,1e-3,9.7,.5,-0,0,0,1,2,3\n"
    b"0.04,upper_arm,0.114,9.800,-0.239,0.0029,-0.0100,0.0056,21.5,-38.2,12.7\n"
)
BODY_START = VALID.index(b"mx,my,mz\n") + len(b"mx,my,mz\n")
SENSORS = [b"upper_arm", b"forearm", b"hand", b"trunk"]
MAGS = [b"20,-40,10", b",,", b"1,2,3", b"5,5,5"]
LONGER = VALID + b"".join(  # each sensor 6- or 9-axis throughout
    b"%r,%s,0.1,9.8,0.2,0.01,0.02,0.03,%s\n" % (0.06 + i * 0.02, SENSORS[i % 4], MAGS[i % 4])
    for i in range(40)
)

pieces = st.sampled_from([
    b"0", b"1", b"9", b"-", b"+", b".", b"e", b",", b"\n", b"\r", b"\r\n", b" ", b"\t", b"#",
    b":", b";", b"=", b'"', b"x", b"\x00", b"\xff", b"\xef\xbb\xbf", "é".encode(), b"nan",
    b"inf", b"forearm", b"hand", b",,,", b"999", b"1e9", b"160", b"-35", b"4999", b",,",
    b"0.0", b"upper_arm", b"trunk",
])


@st.composite
def damaged(draw) -> bytes:
    """A valid file damaged 1 to 4 times anywhere, or only in its data rows."""
    data = bytearray(draw(st.sampled_from([VALID, LONGER])))
    lowest = draw(st.sampled_from([0, BODY_START]))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["insert", "delete", "replace", "swap lines", "truncate"]))
        at = draw(st.integers(min(lowest, len(data)), len(data)))
        if kind == "insert":
            data[at:at] = draw(pieces)
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 5))]
        elif kind == "replace":
            data[at : at + 1] = draw(pieces)
        elif kind == "truncate":
            del data[at:]
        else:
            lines = bytes(data).split(b"\n")
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


@settings(max_examples=1500, deadline=None)
@given(damaged())
@example(VALID[:BODY_START] + b"\xef\xbb\xbf" + VALID[BODY_START:])  # Arrow skips that BOM
@example(VALID.replace(b"0.04,hand", b"0.04,\x00hand"))
def test_fuzz_damaged_files_read_or_are_refused_cleanly(data):
    fast = outcome(data, fast=True)  # anything but InvalidRecording propagates and fails
    assert fast == outcome(data, fast=False)
    if isinstance(fast, str):
        assert fast.startswith("line ") and int(fast.split(":")[0][5:]) >= 1
