"""SPARC and LDLJ against the reference implementation's published figures
(Balasubramanian et al., J NeuroEng Rehabil 2015), their invariances, and the angle
variant on the shared truth files."""

import numpy as np
import pytest
from armtrack.estimator.errors import InvalidArgument, InvalidShape
from armtrack.estimator.metrics import (
    Repetition,
    SmoothnessParams,
    angle_smoothness,
    angular_speed_profile,
    coefficient_of_variation,
    consistency,
    detect_repetitions,
    ldlj,
    repetition_smoothness,
    sparc,
)
from scipy.special import erf

DEG = np.pi / 180
#: The reference's docstring example: speed exp(−5 t²), t = −1 … 0.99 s at 100 Hz.
T_REF = np.arange(-1, 1, 0.01)
V_REF = np.exp(-5 * T_REF ** 2)


def test_reference_figures():
    s, d = sparc(V_REF, 100.0), ldlj(V_REF, 100.0)
    print(f"SPARC {s:.8f} (reference -1.41403), LDLJ {d:.8f} (reference -5.81636)")
    assert T_REF.size == 200
    assert f"{s:.5f}" == "-1.41403"
    assert f"{d:.5f}" == "-5.81636"


def test_dimensionless():
    """A speed in another unit (deg/s instead of rad/s) or twice as fast a movement with
    the same shape gives the same figures."""
    for scale in (1 / DEG, 1e-3):
        assert sparc(scale * V_REF, 100.0) == pytest.approx(sparc(V_REF, 100.0), rel=1e-12)
        assert ldlj(scale * V_REF, 100.0) == pytest.approx(ldlj(V_REF, 100.0), rel=1e-12)
    # the same profile over half the time (speed doubled, sampled at 200 Hz)
    assert ldlj(2 * V_REF, 200.0) == pytest.approx(ldlj(V_REF, 100.0), rel=1e-12)
    assert sparc(2 * V_REF, 200.0, fc=20.0) == pytest.approx(sparc(V_REF, 100.0), rel=1e-12)


def test_two_submovements_are_less_smooth():
    t = np.arange(-1.5, 1.5, 0.01)
    one = np.exp(-5 * t ** 2)
    two = np.exp(-20 * (t + 0.4) ** 2) + np.exp(-20 * (t - 0.4) ** 2)
    print(f"one bump: SPARC {sparc(one, 100.0):.4f}, LDLJ {ldlj(one, 100.0):.4f}; "
          f"two: SPARC {sparc(two, 100.0):.4f}, LDLJ {ldlj(two, 100.0):.4f}")
    assert sparc(two, 100.0) < sparc(one, 100.0) < 0
    assert ldlj(two, 100.0) < ldlj(one, 100.0) < 0


def test_angle_variant_on_the_reference_profile():
    """θ(t) = ∫ exp(−5 t²) dt = √π/(2√5) erf(√5 t): its angular speed is the reference
    profile, up to the differences' truncation error ≤ dt²/3 · max|d³v/dt³| (central
    inside, second-order one-sided at the ends). That error moves the figures by less than
    1e-4 (SPARC) and 1e-3 (LDLJ, whose jerk sees the ends most)."""
    theta = np.sqrt(np.pi) / (2 * np.sqrt(5)) * erf(np.sqrt(5) * T_REF)
    speed, rate = angular_speed_profile(theta, T_REF, T_REF[0], T_REF[-1])
    assert rate == pytest.approx(100.0)
    fine = np.linspace(-1, 1, 20001)
    third = np.abs((-1000 * fine ** 3 + 300 * fine) * np.exp(-5 * fine ** 2)).max()
    assert np.max(np.abs(speed - V_REF)) <= 0.01 ** 2 / 3 * third
    result = angle_smoothness(theta, T_REF, T_REF[0], T_REF[-1])
    print(f"angle variant: SPARC {result.sparc:.6f}, LDLJ {result.ldlj:.6f}; speed within "
          f"{np.max(np.abs(speed - V_REF)):.1e} of the reference profile")
    assert result.sparc == pytest.approx(-1.41403, abs=1e-4)
    assert result.ldlj == pytest.approx(-5.81636, abs=1e-3)


def test_repetition_smoothness_on_truth(recordings_dir):
    table = np.genfromtxt(recordings_dir / "elbow_flexion.truth.csv",
                          delimiter=",", names=True)
    angle, t = table["elbow_flexion"] * DEG, table["t"]
    reps = detect_repetitions(angle, t, include=[(10.5, np.inf)])
    values = repetition_smoothness(angle, t, reps)
    print("elbow_flexion truth: " + "; ".join(
        f"SPARC {v.sparc:.4f} LDLJ {v.ldlj:.4f}" for v in values))
    figures = np.array([[v.sparc, v.ldlj] for v in values])
    assert figures.shape == (5, 2) and np.all(np.isfinite(figures)) and np.all(figures < 0)
    # the five repetitions are the same raised cosine: the same smoothness
    assert np.ptp(figures, axis=0) == pytest.approx([0, 0], abs=0.02)
    noisy = angle + np.random.default_rng(0).normal(0, 0.5 * DEG, angle.size)
    rough = repetition_smoothness(noisy, t, reps)
    filtered = repetition_smoothness(noisy, t, reps, SmoothnessParams(lowpass_hz=3.0))
    print(f"with 0.5 deg noise: LDLJ {rough[0].ldlj:.2f} raw, {filtered[0].ldlj:.2f} "
          f"low-passed at 3 Hz")
    assert rough[0].ldlj < filtered[0].ldlj
    # out and back are one raised-cosine half each: a single speed bump, the smoother part
    outward = repetition_smoothness(angle, t, reps, phase="outward")
    back = repetition_smoothness(angle, t, reps, phase="return")
    print(f"phases: outward SPARC {outward[0].sparc:.4f} LDLJ {outward[0].ldlj:.4f}, return "
          f"SPARC {back[0].sparc:.4f} LDLJ {back[0].ldlj:.4f}")
    assert outward[0].sparc == pytest.approx(back[0].sparc, abs=0.01)
    assert values[0].sparc < outward[0].sparc < 0
    with pytest.raises(InvalidArgument):
        repetition_smoothness(angle, t, reps, phase="up")


def test_consistency_by_hand():
    def rep(amplitude, duration):
        return Repetition(0.0, duration / 2, duration, 1, 0.0, amplitude, amplitude, 1.0)
    reps = [rep(1.0, 2.0), rep(2.0, 2.0), rep(3.0, 2.0)]
    result = consistency(reps)
    assert result.amplitude_cv == pytest.approx(0.5)  # std (ddof 1) 1 over mean 2
    assert result.movement_time_cv == 0.0
    assert consistency(reps[:1]).amplitude_cv is None
    assert consistency(reps, direction=-1).repetitions == 0
    assert coefficient_of_variation(np.array([4.0, 6.0])) == pytest.approx(np.sqrt(2) / 5)
    with pytest.raises(InvalidArgument):
        consistency(reps, direction=2)


def test_invalid_input():
    with pytest.raises(InvalidShape):
        sparc(np.ones(1), 100.0)
    with pytest.raises(InvalidShape):
        ldlj(np.ones((3, 2)), 100.0)
    with pytest.raises(InvalidArgument):
        sparc(np.zeros(50), 100.0)
    with pytest.raises(InvalidArgument):
        ldlj(np.array([0.0, np.nan, 1.0]), 100.0)
    with pytest.raises(InvalidArgument):
        angle_smoothness(np.zeros(10), np.arange(10) / 100, 5.0, 6.0)
    with pytest.raises(InvalidArgument):
        SmoothnessParams(amp_th=1.5)
