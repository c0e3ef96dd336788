"""Hard-iron offsets: the paper's min/max and the sphere fit, on readings of a known field."""

import numpy as np
import pytest
from armtrack.estimator.calibration import minmax_offset, sphere_fit_offset
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.simulation.imu import EARTH_FIELD_UT
from scipy.spatial.transform import Rotation

OFFSET = np.array([12.0, -30.0, 7.5])  # µT, a magnetised part on the board


def readings(orientations, noise=0.0, seed=0):
    R = orientations.as_matrix()
    m = np.einsum("nji,j->ni", R, EARTH_FIELD_UT) + OFFSET
    return m + np.random.default_rng(seed).normal(0, noise, m.shape)


def test_sphere_fit_and_minmax_find_the_offset_from_a_full_turn_about():
    mag = readings(Rotation.random(3000, rng=np.random.default_rng(1)), noise=0.4)
    fit = sphere_fit_offset(mag)
    print(f"sphere fit: offset error {np.linalg.norm(fit.offset - OFFSET):.3f} µT, radius "
          f"{fit.radius:.2f} µT, residual {fit.rms_residual:.2f} µT; min/max error "
          f"{np.linalg.norm(minmax_offset(mag) - OFFSET):.2f} µT")
    np.testing.assert_allclose(fit.offset, OFFSET, atol=0.1)  # 0.4 µT noise, 3000 readings
    assert fit.radius == pytest.approx(48.0, abs=0.1)
    assert fit.rms_residual == pytest.approx(0.4, abs=0.05)  # radial part of the noise
    np.testing.assert_allclose(minmax_offset(mag), OFFSET, atol=2.0)  # extremes carry noise


def test_noise_free_readings_give_the_offset_exactly():
    mag = readings(Rotation.random(50, rng=np.random.default_rng(2)))
    np.testing.assert_allclose(sphere_fit_offset(mag).offset, OFFSET, atol=1e-9)


def test_sphere_fit_works_from_a_partial_turn_where_minmax_cannot():
    """Turning only about one axis by ±60°: min/max misses the centre, the fit does not."""
    turns = Rotation.from_euler("zx", np.column_stack([
        np.linspace(-1, 1, 400), 0.6 * np.sin(np.linspace(0, 9, 400))]))
    mag = readings(turns)
    fit_error = np.linalg.norm(sphere_fit_offset(mag).offset - OFFSET)
    minmax_error = np.linalg.norm(minmax_offset(mag) - OFFSET)
    print(f"partial turn: sphere fit off by {fit_error:.2e} µT, min/max by {minmax_error:.1f} µT")
    assert fit_error < 1e-6 and minmax_error > 5.0


def test_bad_input_is_named():
    with pytest.raises(InvalidShape, match=r"\(N, 3\)"):
        sphere_fit_offset(np.zeros((10, 2)))
    with pytest.raises(InvalidArgument, match="at least 4"):
        sphere_fit_offset(np.zeros((3, 3)))
