"""``qcf``'s gyroscope bias from rests with a phone's sensors (issue 19, single-sensor kits).

A phone's accelerometer is noisier than a kit's IMU (~0.1 m/s² a sample against ~0.04):
the rest detector compared each raw sample's deviation from the low-pass with 0.25 m/s²,
which a 0.1 m/s² noise passes every few samples, so a phone was never at rest, its bias
(up to 0.02 rad/s) never learnt, and its heading drifted by up to a degree a second (an
upper-arm phone: shoulder flexion off by 18–39° RMSE over a minute of side raises). And
the rests after the first one counted as if 10 s of rest already stood behind the bias,
so the T-pose's stillness hardly counted beside the N-pose's first second.
"""

from __future__ import annotations

import numpy as np
import pytest
from armtrack.estimator.orientation import QuaternionComplementaryFilter

G = 9.81
RATE_HZ = 60.0


def still_phone(seconds: float, bias: np.ndarray, seed: int, up=(0.0, 1.0, 0.0),
                acc_noise: float = 0.1):
    """A phone lying still for ``seconds`` at 60 Hz with 2–5 ms jitter: gravity along
    ``up`` (sensor frame) plus ``acc_noise`` [m/s²], the gyroscope ``bias`` plus 0.01
    rad/s noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    t = np.arange(n) / RATE_HZ + rng.uniform(-0.004, 0.004, n)
    acc = G * np.asarray(up, dtype=float) + rng.normal(0.0, acc_noise, (n, 3))
    gyr = bias + rng.normal(0.0, 0.01, (n, 3))
    return t, acc, gyr


@pytest.mark.parametrize("seed", range(5))
def test_a_still_phone_rests_and_learns_its_bias(seed):
    bias = np.random.default_rng(100 + seed).uniform(-0.02, 0.02, 3)
    t, acc, gyr = still_phone(4.0, bias, seed)
    out = QuaternionComplementaryFilter().update(t, acc, gyr)
    error = np.abs(out.gyr_bias[-1] - bias).max()
    print(f"seed {seed}: rest {out.rest.mean():.0%} of the samples, bias error "
          f"{error * 1e3:.2f} mrad/s (bias {np.round(bias * 1e3, 1)} mrad/s)")
    assert out.rest[-1] and out.rest.mean() > 0.3
    # 0.01 rad/s noise over ~2 s of counted samples: ~1 mrad/s; unlearnt it would be 20
    assert error < 0.003


def test_every_rest_counts_by_its_length_until_the_bias_is_well_known():
    """Two short rests (a kit's N-pose and T-pose; a quiet accelerometer, so that the old
    detector saw them too), the bias stepping between them (a sensor warming up): the
    second rest's seconds count as much as the first's, so the estimate moves a good
    part of the way; the old update counted each second of it as a tenth, as if 10 s of
    rest already stood behind the bias."""
    b1 = np.array([0.01, -0.01, 0.015])
    b2 = b1 + np.array([0.008, -0.006, 0.005])  # within what a known bias still calls rest
    t1, acc1, gyr1 = still_phone(3.5, b1, 1, acc_noise=0.02)
    t2, acc2, gyr2 = still_phone(3.5, b2, 2, acc_noise=0.02)
    # between them two seconds of turning about the vertical (gravity stays on y)
    tm = np.arange(1, int(2.0 * RATE_HZ)) / RATE_HZ
    turn = np.column_stack([np.zeros_like(tm), 0.5 * np.sin(np.pi * tm / 2.0),
                            np.zeros_like(tm)])
    t = np.concatenate([t1, t1[-1] + tm, t1[-1] + tm[-1] + 1 / RATE_HZ + t2])
    acc = np.concatenate([acc1, np.tile([0.0, G, 0.0], (len(tm), 1)), acc2])
    gyr = np.concatenate([gyr1, b1 + turn, gyr2])
    out = QuaternionComplementaryFilter().update(t, acc, gyr)
    share = float(np.dot(out.gyr_bias[-1] - b1, b2 - b1) / np.dot(b2 - b1, b2 - b1))
    print(f"the second rest's share of the bias: {share:.2f}")
    # ~2.3 s of the first rest counted, then one 1 s block of the second: ≈ 1 / 3.3
    # (the old update: 0.04)
    assert 0.2 < share < 0.6
