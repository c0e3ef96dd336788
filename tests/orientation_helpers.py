"""Shared pieces of the orientation-filter tests: simulated recordings with ground truth
from the project's simulator, error measures against that truth, and chunked streaming."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
from armtrack.estimator.body import SegmentLengths
from armtrack.estimator.orientation.base import OrientationOutput
from armtrack.estimator.rotations import quat_to_matrix
from armtrack.estimator.simulation import (
    ImuErrors,
    Motion,
    Profile,
    SimulationConfig,
    Stance,
    body_motion,
    default_mount,
    exercise_motion,
    simulate,
    synthesize_imu,
)

#: Sensor errors of the simulator's default kit (``SimulationConfig``) with a known bias.
REALISTIC = dict(gyro_noise=0.004, acc_noise=0.04, mag_noise=0.4)
BIAS = (0.010, -0.008, 0.006)
#: The exercise is scored from here on (``simulation.SCORED_FROM_S``).
SCORED_FROM_S = 10.5


@dataclass(frozen=True)
class Take:
    """One sensor's signals and its true ``R_world_sensor`` (N, 3, 3)."""

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None
    R_true: np.ndarray


@cache
def elbow_flexion(sensor: str = "forearm", nine_axis: bool = True, seed: int = 0) -> Take:
    """``simulate``'s elbow flexion (calibration, 5 repetitions to 120°) for one sensor:
    random mounting, realistic noise and a random bias up to 0.012 rad/s per axis."""
    sim = simulate(SimulationConfig(exercise="elbow_flexion", sensors=(sensor,),
                                    nine_axis=nine_axis, seed=seed))
    s = sim.recording.sensors[sensor]
    return Take(s.t, s.acc, s.gyr, s.mag, sim.truth.R_world_sensor[sensor])


@cache
def known_bias_take(exercise: str = "elbow_flexion", nine_axis: bool = True,
                    duration_s: float = 35.0, pose: tuple[tuple[str, float], ...] = ()
                    ) -> Take:
    """The forearm sensor (default mounting, right arm, facing 30° from east) with the
    realistic noise and the known gyroscope bias ``BIAS``; ``pose`` holds joints still at
    the given angles [rad] instead of ``exercise``."""
    lengths = SegmentLengths.from_height(1.75)
    t = np.arange(0.0, duration_s, 0.01)
    if pose:
        motion = Motion(joints={name: Profile(offset=angle) for name, angle in pose})
    else:
        motion = exercise_motion(exercise)
    body = body_motion(motion, "right", lengths, t, Stance(heading=np.deg2rad(30.0)))
    sig = synthesize_imu(body, "forearm", default_mount("forearm", "right", lengths),
                         nine_axis=nine_axis, errors=ImuErrors(**REALISTIC, gyro_bias=BIAS),
                         rng=np.random.default_rng(7))
    return Take(sig.t, sig.acc, sig.gyr, sig.mag, sig.R_world_sensor)


def angle_error_deg(R_true: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle [deg] (N,) of ``R_trueᵀ R_est``, the whole orientation error."""
    D = np.swapaxes(R_true, -1, -2) @ quat_to_matrix(q)
    cos = (np.trace(D, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def tilt_error_deg(R_true: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle [deg] (N,) between the true and the estimated world vertical in the sensor
    frame (``R_world_sensorᵀ (0, 0, 1)``): the inclination error, blind to heading."""
    up_true = R_true[:, 2, :]
    up_est = quat_to_matrix(q)[:, 2, :]
    cross = np.linalg.norm(np.cross(up_true, up_est), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(up_true * up_est, axis=-1)))


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def stream(make_filter: Callable, take: Take, rng: np.random.Generator,
           max_chunk: int = 400) -> OrientationOutput:
    """Feed ``take`` to a fresh filter in chunks of random sizes (some empty, some of one
    sample) and join the outputs."""
    f = make_filter()
    n = take.t.size
    bounds = [0]
    while bounds[-1] < n:
        bounds.append(min(n, bounds[-1] + int(rng.choice([0, 1, 2, rng.integers(3, max_chunk)]))))
    parts = [f.update(take.t[a:b], take.acc[a:b], take.gyr[a:b],
                      None if take.mag is None else take.mag[a:b])
             for a, b in itertools.pairwise(bounds)]
    return OrientationOutput(*(np.concatenate([getattr(p, k) for p in parts])
                               for k in ("q", "gyr_bias", "rest", "mag_disturbed")))


def assert_valid_output(out: OrientationOutput, n: int) -> None:
    """Shapes, dtypes, unit quaternions, no NaN."""
    assert out.q.shape == (n, 4) and out.gyr_bias.shape == (n, 3)
    assert out.rest.shape == (n,) and out.mag_disturbed.shape == (n,)
    assert out.rest.dtype == bool and out.mag_disturbed.dtype == bool
    assert np.all(np.isfinite(out.q)) and np.all(np.isfinite(out.gyr_bias))
    np.testing.assert_allclose(np.linalg.norm(out.q, axis=1), 1.0, atol=1e-12)
