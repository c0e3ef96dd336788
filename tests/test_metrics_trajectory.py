"""Trajectory errors (seed paper eq. 17) against hand-computed arrays, numpy one-liners and
the shared truth positions."""

import numpy as np
import pytest
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.metrics import position_errors, series_errors
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

POINTS = ("shoulder", "elbow", "wrist", "hand")


def test_series_by_hand():
    e = series_errors(np.array([1.0, 2.0, 3.0, 4.0]), np.array([1.0, 1.0, 1.0, 1.0]))
    # errors 0, 1, 2, 3: MAE 6/4, max 3, RMSE sqrt(14/4)
    assert (e.mae, e.max_error, e.rmse) == pytest.approx((1.5, 3.0, np.sqrt(3.5)), rel=1e-15)
    assert (e.samples, e.missing) == (4, 0)
    e = series_errors(np.array([-2.0, 1.0]), np.array([1.0, 1.0]))
    assert (e.mae, e.max_error, e.rmse) == pytest.approx((1.5, 3.0, np.sqrt(4.5)))


def test_missing_estimates_are_skipped_and_counted():
    e = series_errors(np.array([1.0, np.nan, 3.0, np.nan]), np.zeros(4))
    assert (e.mae, e.max_error, e.rmse) == pytest.approx((2.0, 3.0, np.sqrt(5.0)))
    assert (e.samples, e.missing) == (2, 2)
    estimate = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [1.0, 2.0, 2.0], [np.nan, 0.0, 0.0]])
    e = position_errors(estimate, np.zeros((4, 3)))
    # distances 0, 5, 3 and one missing: MAE 8/3, max 5, RMSE sqrt(34/3)
    assert (e.mae, e.max_error, e.rmse) == pytest.approx((8 / 3, 5.0, np.sqrt(34 / 3)))
    assert (e.samples, e.missing) == (3, 1)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 50), st.just(3)),
              elements=st.floats(-10, 10)),
       arrays(np.float64, (50, 3), elements=st.floats(-10, 10)),
       st.lists(st.booleans(), min_size=50, max_size=50))
def test_positions_against_numpy_one_liners(estimate, truth, lost):
    truth = truth[: len(estimate)]
    lost = np.array(lost[: len(estimate)])
    lost[0] = False
    estimate = estimate.copy()
    estimate[lost, 1] = np.nan
    e = position_errors(estimate, truth)
    d = np.sqrt(((estimate - truth) ** 2).sum(axis=1))[~lost]
    assert e.mae == pytest.approx(d.mean(), rel=1e-12, abs=1e-12)
    assert e.max_error == pytest.approx(d.max(), rel=1e-12, abs=1e-12)
    assert e.rmse == pytest.approx(np.sqrt((d ** 2).mean()), rel=1e-12, abs=1e-12)
    assert (e.samples, e.missing) == (d.size, int(lost.sum()))
    s = series_errors(estimate[:, 0], truth[:, 0])
    d1 = np.abs(estimate[:, 0] - truth[:, 0])
    assert (s.mae, s.max_error, s.rmse) == pytest.approx(
        (d1.mean(), d1.max(), np.sqrt((d1 ** 2).mean())), rel=1e-12, abs=1e-12)


def test_truth_positions_shifted(recordings_dir):
    """Every point of a truth file moved by (0.01, 0.02, 0.02) m is 0.03 m off everywhere."""
    table = np.genfromtxt(recordings_dir / "elbow_flexion.truth.csv",
                          delimiter=",", names=True)
    for point in POINTS:
        truth = np.stack([table[f"{point}_{a}"] for a in "xyz"], axis=-1)
        itself = position_errors(truth, truth)
        assert (itself.mae, itself.max_error, itself.rmse) == (0.0, 0.0, 0.0)
        e = position_errors(truth + np.array([0.01, 0.02, 0.02]), truth)
        print(f"{point}: MAE {e.mae:.6f} m, max {e.max_error:.6f} m, RMSE {e.rmse:.6f} m "
              f"over {e.samples} samples")
        assert (e.mae, e.max_error, e.rmse) == pytest.approx((0.03, 0.03, 0.03), rel=1e-12)


def test_invalid_input():
    with pytest.raises(InvalidShape):
        series_errors(np.zeros(3), np.zeros(4))
    with pytest.raises(InvalidShape):
        series_errors(np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(InvalidShape):
        position_errors(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(InvalidArgument):
        series_errors(np.zeros(3), np.array([0.0, np.nan, 0.0]))
    with pytest.raises(InvalidArgument):
        series_errors(np.full(3, np.nan), np.zeros(3))
    with pytest.raises(InvalidArgument):
        series_errors(np.array([0.0, np.inf]), np.zeros(2))
