"""IMU synthesis: what a sensor mounted on a moving segment measures.

For a sensor with orientation ``R_world_sensor = R_world_segment R_segment_sensor`` at the
point ``p`` (fixed in its segment):

* gyroscope: ``ω_sensor = R_segment_sensorᵀ ω_segment`` [rad/s] (+ bias, + noise);
* accelerometer: specific force ``f = R_world_sensorᵀ (p̈ − g)`` [m/s²] with
  ``g = (0, 0, −9.81)``, so at rest the axis pointing up reads +9.81 (+ bias, + noise);
* magnetometer: ``m = R_world_sensorᵀ B(p, t)`` [µT], the earth's field plus any
  disturbance at the sensor's place (+ noise); absent on a 6-axis sensor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..arm.joints import SEGMENT_OF_SENSOR
from ..body import SegmentLengths, Side
from ..errors import InvalidArgument
from ..rotations import elemental
from .body_motion import BodyMotion

GRAVITY = np.array([0.0, 0.0, -9.81])

#: The earth's field [µT] in the world frame, ENU (x east, y north, z up): 48 µT pointing
#: north and down at 65° inclination, as in central Europe.
EARTH_FIELD_UT = np.array([0.0, 48.0 * np.cos(np.deg2rad(65.0)), -48.0 * np.sin(np.deg2rad(65.0))])

#: The point each sensor's segment hangs from (its origin for the sensor offset).
SEGMENT_ORIGIN = {"thorax": "sternal_notch", "clavicle": "sternal_notch",
                  "upper_arm": "shoulder", "forearm": "elbow", "hand": "wrist"}


@dataclass(frozen=True)
class Mount:
    """A sensor on its segment: ``R_segment_sensor`` and its place ``offset_m`` [m] in the
    segment frame, from the segment's origin point (sternal notch, shoulder, elbow, wrist)."""

    R_segment_sensor: np.ndarray
    offset_m: np.ndarray


def default_mount_rotation(sensor: str, side: Side) -> np.ndarray:
    """``R_segment_sensor`` of the default mounting (``docs/spec/recording.md``)."""
    turn = elemental("y", np.pi) if side == "left" else np.eye(3)
    if sensor in ("upper_arm", "forearm", "hand"):
        return turn  # lateral surface, +Y proximal, +Z out of the skin
    if sensor == "clavicle":
        return turn  # on top: +Z laterally along the clavicle, +Y up (out of the skin)
    if sensor == "trunk":
        # On the sternum: +Y up, +Z out of the skin (anterior), so +X = Y × Z is to the left.
        return np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    raise InvalidArgument(f"unknown sensor {sensor!r}")


def default_mount(sensor: str, side: Side, lengths: SegmentLengths) -> Mount:
    """The default mounting, at a typical place on the segment's surface."""
    lateral = -1.0 if side == "left" else 1.0
    offsets = {
        "trunk": (0.03, -0.12, 0.0),
        "clavicle": (0.0, 0.02, lateral * 0.5 * lengths.clavicle),
        "upper_arm": (0.0, -0.5 * lengths.upper_arm, lateral * 0.045),
        "forearm": (0.0, -0.65 * lengths.forearm, lateral * 0.03),
        "hand": (0.0, -0.35 * lengths.hand, lateral * 0.02),
    }
    return Mount(default_mount_rotation(sensor, side), np.array(offsets[sensor]))


@dataclass(frozen=True)
class Dipole:
    """A magnetic disturbance: a dipole at ``position_m`` (world) whose field is
    ``strength_ut`` at 0.1 m on its axis ``axis`` (world), present from ``start_s`` to
    ``end_s``."""

    position_m: tuple[float, float, float]
    strength_ut: float
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    start_s: float = -np.inf
    end_s: float = np.inf

    def field(self, p: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Field [µT] at points ``p`` (N, 3) and times ``t`` (N,)."""
        r = p - np.asarray(self.position_m)
        d = np.linalg.norm(r, axis=-1, keepdims=True).clip(0.02)
        rhat = r / d
        m = np.asarray(self.axis, dtype=float) / np.linalg.norm(self.axis)
        # B = k (3 (m·r̂) r̂ − m) / d³, scaled so |B| = strength at 0.1 m on the axis
        k = self.strength_ut * 0.1**3 / 2.0
        B = k * (3.0 * (rhat @ m)[:, None] * rhat - m) / d**3
        active = (t >= self.start_s) & (t <= self.end_s)
        return B * active[:, None]


@dataclass(frozen=True)
class ImuErrors:
    """Sensor errors: white noise (rms per axis) and biases.

    gyro_noise [rad/s], acc_noise [m/s²], mag_noise [µT]; gyro_bias [rad/s] (3,), constant;
    gyro_bias_walk [rad/s/√s], a random walk added to it; acc_bias [m/s²] (3,);
    mag_hard_iron [µT] (3,), a constant offset in the sensor frame.
    """

    gyro_noise: float = 0.0
    acc_noise: float = 0.0
    mag_noise: float = 0.0
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_walk: float = 0.0
    acc_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_hard_iron: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ImuSignals:
    """Measured signals of one sensor at times ``t`` (N,): ``acc`` [m/s²], ``gyr`` [rad/s],
    ``mag`` [µT] or None, and the true ``R_world_sensor`` (N, 3, 3)."""

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None
    R_world_sensor: np.ndarray


@dataclass(frozen=True)
class MagneticEnvironment:
    """The earth's field [µT] (world) and any disturbances."""

    earth_ut: np.ndarray = field(default_factory=lambda: EARTH_FIELD_UT.copy())
    disturbances: tuple[Dipole, ...] = ()

    def field(self, p: np.ndarray, t: np.ndarray) -> np.ndarray:
        B = np.broadcast_to(self.earth_ut, p.shape).copy()
        for dipole in self.disturbances:
            B += dipole.field(p, t)
        return B


def synthesize_imu(body: BodyMotion, sensor: str, mount: Mount, *, nine_axis: bool = True,
                   errors: ImuErrors = ImuErrors(), environment: MagneticEnvironment | None = None,
                   rng: np.random.Generator | None = None,
                   gyro_body: BodyMotion | None = None) -> ImuSignals:
    """What ``sensor`` (a name of ``SENSOR_NAMES``) measures over ``body.t``.

    ``gyro_body``: the same motion at the times the gyroscope's samples really describe,
    for a kit whose gyroscope lags its accelerometer by d: ``body.t − d`` (None: in step)."""
    if sensor not in SEGMENT_OF_SENSOR:
        raise InvalidArgument(f"unknown sensor {sensor!r}")
    segment = SEGMENT_OF_SENSOR[sensor]
    frame = body.frames[segment]
    point = body.points[SEGMENT_ORIGIN[segment]].offset(frame, mount.offset_m)
    R_ws = frame.R @ mount.R_segment_sensor
    R_sw = np.swapaxes(R_ws, -1, -2)
    gyr = frame.omega @ mount.R_segment_sensor
    if gyro_body is not None:
        if gyro_body.t.shape != body.t.shape:
            raise InvalidArgument("gyro_body must give the motion at one time per sample")
        gyr = gyro_body.frames[segment].omega @ mount.R_segment_sensor
    acc = np.einsum("nij,nj->ni", R_sw, point.a - GRAVITY)
    n = body.t.size
    rng = rng or np.random.default_rng(0)
    bias = np.broadcast_to(np.asarray(errors.gyro_bias, float), (n, 3)).copy()
    if errors.gyro_bias_walk > 0 and n > 1:
        dt = np.diff(body.t, prepend=body.t[0])
        steps = rng.normal(0.0, 1.0, (n, 3)) * errors.gyro_bias_walk * np.sqrt(dt)[:, None]
        bias += np.cumsum(steps, axis=0)
    gyr = gyr + bias + rng.normal(0.0, errors.gyro_noise, (n, 3))
    acc = acc + np.asarray(errors.acc_bias) + rng.normal(0.0, errors.acc_noise, (n, 3))
    mag = None
    if nine_axis:
        env = environment or MagneticEnvironment()
        mag = np.einsum("nij,nj->ni", R_sw, env.field(point.p, body.t))
        mag = mag + np.asarray(errors.mag_hard_iron) + rng.normal(0.0, errors.mag_noise, (n, 3))
    return ImuSignals(t=body.t, acc=acc, gyr=gyr, mag=mag, R_world_sensor=R_ws)
