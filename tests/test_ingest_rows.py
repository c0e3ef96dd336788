"""The hot-path check of a samples message's rows: the compiled one-pass check judges
every row exactly as the whole-array reference does, boundaries included."""

import numpy as np
from armtrack.server.ingest.protocol import plausible_numpy, plausible_rows
from hypothesis import given, settings
from hypothesis import strategies as st

#: values that sit on or near the rules: the range limits, their neighbours, non-finite
EDGES = [0.0, -0.0, 1.0, -1.0, 160.0, np.nextafter(160.0, 200.0), 35.0,
         np.nextafter(35.0, 0.0), 5000.0, 92.37604307034012, 1e308, np.inf, -np.inf,
         np.nan, 5e-324]


@st.composite
def rows(draw):
    n = draw(st.integers(1, 6))
    values = st.one_of(st.sampled_from(EDGES), st.floats(-6000, 6000, allow_nan=False))
    data = np.array(draw(st.lists(st.lists(values, min_size=10, max_size=10),
                                  min_size=n, max_size=n)), dtype=np.float64)
    if draw(st.booleans()):  # mostly time-ordered, as real messages are
        data[:, 0] = np.sort(data[:, 0])
    if draw(st.booleans()):  # a 6-axis row set: null magnetometer
        data[:, 7:] = np.nan
    return data


@settings(max_examples=3000, deadline=None)
@given(rows(), st.booleans())
def test_the_compiled_row_check_agrees_with_the_array_reference(data, nine_axis):
    assert plausible_rows(data, nine_axis) == plausible_numpy(data, nine_axis)


def test_realistic_rows_pass_and_each_fault_fails():
    rng = np.random.default_rng(2)
    data = np.column_stack([np.arange(10) * 0.01, rng.normal(0, 5, (10, 3)),
                            rng.normal(0, 1, (10, 3)), rng.normal(0, 40, (10, 3))])
    assert plausible_rows(data, True) and plausible_numpy(data, True)
    for row, col, value in ((3, 2, 200.0), (4, 5, 40.0), (5, 8, 6000.0), (6, 0, -1.0),
                            (2, 1, np.nan), (7, 9, np.inf)):
        bad = data.copy()
        bad[row, col] = value
        assert not plausible_rows(bad, True) and not plausible_numpy(bad, True), (row, col)
    six = data.copy()
    six[:, 7:] = np.nan
    assert plausible_rows(six, False) and not plausible_rows(six, True)
    assert not plausible_rows(data, False)  # a 6-axis sensor with magnetometer numbers


def test_the_quick_row_conversion_refuses_with_the_same_reasons_as_the_step_by_step_one():
    """``check_samples``'s quick path (one type scan, one conversion) hands every odd
    message to the step-by-step checks, which name the fault; numbers too large for a
    float64 (a mark's ``t`` found by the fuzz test) are refused, not raised."""
    import pytest
    from armtrack.server.ingest.protocol import (
        NotJsonNumber,
        Refused,
        check_hello,
        check_mark,
        check_samples,
    )

    hello = check_hello({"type": "hello", "protocol": 1, "device": "k", "side": "right",
                         "sensors": ["forearm"], "rate_hz": 100, "nine_axis": True,
                         "resume": None})
    good = [[0.01 * i, 0, 0, 9.81, 0, 0, 0, 20, 5, -40] for i in range(10)]
    assert check_samples({"sensor": "forearm", "rows": good}, 0, hello, {}).rows.shape \
        == (10, 10)
    cases = {
        "every row must be a list of 10": [good[0], good[1][:9]],
        "every row must be a list": [good[0], 3.0],
        r"numbers \(or null magnetometer\), got a str": [good[0], [*good[1][:9], "1.5"]],
        "got true/false": [good[0], [*good[1][:9], True]],
        "JSON allows": [[*good[0][:9], NotJsonNumber("NaN")]],
        "too large for a float64": [[*good[0][:9], 10 ** 400]],
        "every row must be a list of": ["abcdefghij"],
        "row values must be numbers": [[[1.0]] * 10],
    }
    for reason, rows in cases.items():
        with pytest.raises(Refused, match=reason):
            check_samples({"sensor": "forearm", "rows": rows}, 7, hello, {})
    with pytest.raises(Refused, match="t must be a finite number"):
        check_mark({"t": 10 ** 400, "label": "npose"}, 8)


# -- parse's typed fast path for samples messages ---------------------------------------

#: JSON values a kit might put in a row, good and bad: numbers in every notation, ints
#: past 64 bits and past a float64, null, bools, strings, NaN and friends, nested lists
ROW_VALUES = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda x: f"{x:.20e}"),
    st.floats(-200, 200).map(lambda x: f"{x:.3f}"),
    st.integers(-(10**30), 10**30).map(str),
    st.sampled_from(["null", "true", "false", '"1.5"', "NaN", "-Infinity", "1e400",
                     "-1e-400", "-0", "0e0", "1E5", "[]", "{}", "9007199254740993",
                     "1" + "0" * 320]),
)


@st.composite
def samples_texts(draw):
    width = draw(st.sampled_from([10, 10, 10, 9, 11]))
    n = draw(st.sampled_from([1, 2, 10, 0]))
    rows = [draw(st.lists(ROW_VALUES, min_size=width, max_size=width)) for _ in range(n)]
    if draw(st.booleans()):  # mostly plausible, time-ordered rows
        rows = [[f"{0.01 * i:.2f}", *(f"{v:.4f}" for v in draw(st.lists(
            st.floats(-30, 30), min_size=6, max_size=6))),
            *(["null"] * 3 if draw(st.booleans()) else ["20.5", "-3", "41.25"])]
            for i in range(n)]
    body = "[" + ",".join("[" + ",".join(row) + "]" for row in rows) + "]"
    # (not a seq past 64 bits: orjson reads it as a float, the typed path as the whole
    # number it is, see the test below)
    seq = draw(st.sampled_from(["7", "-1", "true", "7.0", '"7"', str(2**63)]))
    sensor = draw(st.sampled_from(['"upperarm"', '"shin"', "3"]))
    extra = draw(st.sampled_from(["", ',"extra":[1,{"a":null}]', ',"rows":[]']))
    return f'{{"type":"samples","seq":{seq},"sensor":{sensor},"rows":{body}{extra}}}'


def _outcome(message, nine_axis):
    from armtrack.server.ingest.protocol import Hello, Refused, check_samples, check_seq

    hello = Hello("kit", "right", ("upperarm", "forearm"), 100.0, nine_axis, None)
    try:
        seq = check_seq(message)
        item = check_samples(message, seq, hello, {})
    except Refused as refused:
        return ("refused", refused.reason, refused.seq)
    return ("accepted", item.seq, item.sensor, item.rows.dtype, item.rows.shape,
            item.rows.tobytes())


@settings(max_examples=3000, deadline=None)
@given(samples_texts(), st.booleans())
def test_the_typed_samples_decoding_gives_what_the_general_parse_gives(text, nine_axis):
    """``parse`` hands a well-formed samples message on with its rows already float64;
    accepted or refused, the outcome (the doubles bit for bit, or the reason) is what
    the general path (orjson, then the step-by-step checks) gives."""
    import orjson
    from armtrack.server.ingest.protocol import Refused, parse

    try:
        general = orjson.loads(text)
    except orjson.JSONDecodeError:
        general = None  # NaN, 1e400 …: the slow path's own business, no fast path taken
    try:
        fast = parse(text)
    except Refused:
        assert general is None
        return
    if general is None:
        assert not isinstance(fast["rows"], np.ndarray)  # the standard library parsed it
        return
    assert _outcome(fast, nine_axis) == _outcome(general, nine_axis)


def test_the_typed_samples_decoding_is_taken_for_good_messages():
    import pytest
    from armtrack.server.ingest.protocol import Refused, parse

    nine = parse('{"type":"samples","seq":3,"sensor":"upperarm","rows":'
                 '[[0.01,1,2,3,4,5,6,7,8,9],[0.02,1,2,3,4,5,6,7,8,9.5]]}')
    six = parse('{"type":"samples","seq":3,"sensor":"upperarm","rows":'
                '[[0.01,1,2,3,4,5,6,null,null,null]]}')
    assert nine["rows"].shape == (2, 10) and nine["rows"][1, 9] == 9.5
    assert np.isnan(six["rows"][0, 7:]).all() and six["rows"].dtype == np.float64
    with pytest.raises(Refused, match="needs a string field 'type'"):  # no type: no samples
        parse('{"seq":3,"sensor":"upperarm","rows":[[0,1,2,3,4,5,6,7,8,9]]}')
    for other in ('{"type":"mark","seq":3,"t":0.5,"label":"npose"}',
                  '{"type":"samples","seq":3,"sensor":"upperarm","rows":[[0,1,2,3,4,5,6,7,8,true]]}'):
        message = parse(other)
        assert not isinstance(message.get("rows"), np.ndarray)
    # a seq past 64 bits stays the whole number it is (orjson would give a float, and the
    # message would be refused as "not a whole number" instead of "ahead")
    big = parse(f'{{"type":"samples","seq":{2**70},"sensor":"upperarm","rows":'
                '[[0.01,1,2,3,4,5,6,7,8,9]]}')
    assert big["seq"] == 2**70 and type(big["seq"]) is int
