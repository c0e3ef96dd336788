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
