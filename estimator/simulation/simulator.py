"""Simulated recordings with ground truth: a motion, a body, a kit of sensors and their
faults → a :class:`~armtrack.estimator.recording.Recording` and its :class:`Truth`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..arm.forward import POINTS, forward_kinematics
from ..arm.joints import ANGLE_NAMES, ELEVATION, SEGMENT_OF_SENSOR
from ..body import SENSOR_NAMES, SegmentLengths, Side
from ..errors import InvalidArgument
from ..orientation.qcf import check_gyro_delay
from ..recording import Pose, Recording, SensorStream
from ..recording.model import GYRO_DELAY_KEY
from ..rotations import angle_between, elemental
from .body_motion import Stance, body_motion
from .imu import (
    SEGMENT_ORIGIN,
    Dipole,
    ImuErrors,
    MagneticEnvironment,
    Mount,
    default_mount,
    synthesize_imu,
)
from .points import WRIST_SOURCES, wrist_points
from .profiles import Excursion, Motion, Profile, Sine
from .scenarios import NPOSE_S, calibration_offset, exercise_motion, pose_windows


@dataclass(frozen=True)
class SimulationConfig:
    """Everything a simulated session varies. Angles in degrees here (a user's knobs).

    sensors: sensor names worn. rate_hz: nominal rate. jitter_s: each sample is taken and
    stamped up to this far from its nominal time (uniform). lost_fraction: share of samples
    dropped at random, per sensor. mount_axial_deg / mount_tilt_deg: the largest random
    turn of a sensor about its segment's long axis and tilt away from it. gyro_bias_max:
    the largest constant gyroscope bias per axis [rad/s]. gyro_delay_s: the kit's
    gyroscopes lag its accelerometers by this [s] (a sample stamped t reads the rate of
    t − gyro_delay_s; the hardware's timing, ``docs/extensions/gyro-delay.md``);
    declare_gyro_delay: the recording declares it (header ``gyro_delay_s``). npose_s: how
    long the N-pose is held from the start [s] (3.0: the shared recordings' timeline); the
    T-pose, the exercise and its scoring come that much later (``calibration_offset``).
    """

    exercise: str = "elbow_flexion"
    side: Side = "right"
    height_m: float = 1.75
    rate_hz: float = 100.0
    nine_axis: bool = True
    sensors: tuple[str, ...] = ("upper_arm", "forearm", "hand")
    repetitions: int | None = None
    amplitude_deg: float | None = None
    calibration: bool = True
    tail_s: float = 2.0
    seed: int = 0
    errors: ImuErrors = field(default_factory=lambda: ImuErrors(
        gyro_noise=0.004, acc_noise=0.04, mag_noise=0.4))
    gyro_bias_max: float = 0.012
    jitter_s: float = 0.0
    lost_fraction: float = 0.0
    mount_axial_deg: float = 25.0
    mount_tilt_deg: float = 8.0
    magnet_near_hand: bool = False
    heading_deg: float = 30.0
    wrist_points: str | None = None
    start_disturbance_s: tuple[float, float] | None = None
    start_disturbance_ut: tuple[float, float] = (20.0, 50.0)
    trunk_sway: tuple[float, float] | None = None
    pack_size: int = 1
    gyro_delay_s: float = 0.0
    declare_gyro_delay: bool = False
    npose_s: float = NPOSE_S

    def __post_init__(self) -> None:
        check_gyro_delay(self.gyro_delay_s, "SimulationConfig.gyro_delay_s")
        calibration_offset(self.npose_s)
        unknown = set(self.sensors) - set(SENSOR_NAMES)
        if unknown or not self.sensors:
            raise InvalidArgument(f"sensors must be some of {SENSOR_NAMES}, got {self.sensors}")
        if not 1.0 <= self.rate_hz <= 2000.0:
            raise InvalidArgument(f"rate_hz must be within 1–2000 Hz, got {self.rate_hz}")
        if not 0.0 <= self.lost_fraction < 0.5:
            raise InvalidArgument(f"lost_fraction must be in [0, 0.5), got {self.lost_fraction}")
        if self.wrist_points not in (None, *WRIST_SOURCES):
            raise InvalidArgument(f"wrist_points must be one of {', '.join(WRIST_SOURCES)}, "
                                  f"got {self.wrist_points!r}")
        if not 1 <= self.pack_size <= 100:
            raise InvalidArgument(f"pack_size must be within 1–100, got {self.pack_size}")
        if not 0.0 <= self.jitter_s < 0.5 / self.rate_hz:
            raise InvalidArgument(
                f"jitter_s must be below half a sample period ({0.5 / self.rate_hz} s), "
                f"got {self.jitter_s}")


@dataclass(frozen=True)
class Truth:
    """Ground truth on the nominal sample grid ``t`` [s] (N,): joint angles [rad] by name
    (with ``shoulder_elevation``), positions [m] in the thorax frame by point, the true
    ``R_world_sensor`` of each sensor at its own sample times, and each joint's planned
    excursions from rest (its repetitions and held postures, in time order; the
    calibration poses are not among them)."""

    t: np.ndarray
    angles: dict[str, np.ndarray]
    positions: dict[str, np.ndarray]
    mounts: dict[str, Mount]
    R_world_sensor: dict[str, np.ndarray]
    excursions: dict[str, tuple[Excursion, ...]] = field(default_factory=dict)

    def repetitions(self, angle: str) -> tuple[Excursion, ...]:
        """``angle``'s repetitions (its excursions but the held postures), in time order."""
        return tuple(e for e in self.excursions.get(angle, ()) if not e.held)

    def table(self) -> tuple[list[str], np.ndarray]:
        """Columns and values as in ``shared/data/recordings/*.truth.csv`` (degrees, m)."""
        columns = ["t", *ANGLE_NAMES, ELEVATION] + [f"{p}_{a}" for p in POINTS for a in "xyz"]
        values = np.column_stack([self.t, *(np.rad2deg(self.angles[k])
                                            for k in (*ANGLE_NAMES, ELEVATION)),
                                  *(self.positions[p] for p in POINTS)])
        return columns, values


@dataclass(frozen=True)
class Simulation:
    recording: Recording
    truth: Truth


def random_mount(sensor: str, config: SimulationConfig, lengths: SegmentLengths,
                 rng: np.random.Generator) -> Mount:
    """The default mounting turned by up to ``mount_axial_deg`` about the segment's long
    axis and tilted by up to ``mount_tilt_deg``, its place moved by up to 1 cm."""
    mount = default_mount(sensor, config.side, lengths)
    axial = np.deg2rad(rng.uniform(-config.mount_axial_deg, config.mount_axial_deg))
    tilt = np.deg2rad(rng.uniform(-config.mount_tilt_deg, config.mount_tilt_deg, 2))
    long_axis = "z" if sensor == "clavicle" else "y"
    tilt_axes = ("x", "y") if sensor == "clavicle" else ("x", "z")
    R = (elemental(long_axis, axial) @ elemental(tilt_axes[0], tilt[0])
         @ elemental(tilt_axes[1], tilt[1]))
    return Mount(R @ mount.R_segment_sensor, mount.offset_m + rng.uniform(-0.01, 0.01, 3))


def start_disturbances(motion: Motion, config: SimulationConfig, lengths: SegmentLengths,
                       stance: Stance, rng: np.random.Generator) -> list[Dipole]:
    """One magnet per sensor, 8 cm from where the sensor is at t = 0 (to its side, a
    random axis), whose field at the sensor is drawn from ``start_disturbance_ut`` and
    which is there from the start for a time drawn from ``start_disturbance_s``: sensors
    a few decimetres apart see their own disturbance (a dipole fades with the cube of the
    distance)."""
    assert config.start_disturbance_s is not None
    start = body_motion(motion, config.side, lengths, np.zeros(1), stance)
    out = []
    for sensor in (s for s in SENSOR_NAMES if s in config.sensors):
        segment = SEGMENT_OF_SENSOR[sensor]
        mount = default_mount(sensor, config.side, lengths)
        where = start.points[SEGMENT_ORIGIN[segment]].offset(start.frames[segment],
                                                            mount.offset_m).p[0]
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        axis = rng.normal(size=3)
        # |B| on the axis at 0.1 m is strength_ut; at 8 cm off at a random angle it is
        # about (0.1 / 0.08)³ times that, times 1…2 by the angle: aim at the middle
        field = rng.uniform(*config.start_disturbance_ut)
        strength = field / (0.1 / 0.08) ** 3 / 1.5
        out.append(Dipole(position_m=tuple(where + 0.08 * direction), strength_ut=strength,
                          axis=tuple(axis), end_s=rng.uniform(*config.start_disturbance_s)))
    return out


def sample_times(duration: float, config: SimulationConfig, rng: np.random.Generator) -> np.ndarray:
    """One sensor's sample times [s]: nominal grid, jitter, lost samples."""
    n = int(np.floor(duration * config.rate_hz)) + 1
    t = np.arange(n) / config.rate_hz
    if config.jitter_s:
        t = t + rng.uniform(-config.jitter_s, config.jitter_s, n)
    if config.lost_fraction:
        keep = rng.random(n) >= config.lost_fraction
        keep[[0, -1]] = True
        t = t[keep]
    return t


def simulate(config: SimulationConfig = SimulationConfig(), motion: Motion | None = None,
             lengths: SegmentLengths | None = None) -> Simulation:
    """A recording of ``config.exercise`` (or of ``motion``) with its ground truth."""
    rng = np.random.default_rng(config.seed)
    lengths = lengths or SegmentLengths.from_height(config.height_m)
    if motion is None:
        motion = exercise_motion(config.exercise, repetitions_count=config.repetitions,
                                 amplitude_deg=config.amplitude_deg,
                                 calibration=config.calibration, npose_s=config.npose_s)
        if config.trunk_sway is not None:
            amplitude, frequency = config.trunk_sway
            motion = replace(motion, trunk={
                "trunk_flexion": Profile(sines=(Sine(np.deg2rad(amplitude), frequency),)),
                "trunk_lateral": Profile(sines=(Sine(np.deg2rad(0.5 * amplitude),
                                                     0.7 * frequency, 1.0),))})
    offset = calibration_offset(config.npose_s) if config.calibration else 0.0
    duration = max(motion.end_time(), 10.0 + offset if config.calibration else 0.0) \
        + config.tail_s
    stance = Stance(heading=np.deg2rad(config.heading_deg))
    environment = MagneticEnvironment()
    if config.magnet_near_hand and config.nine_axis:
        # A magnet (a phone, a table's steel frame) 12 cm beside the resting hand, present
        # from the exercise's start: strong where the hand rests, fading as it moves away.
        rest = body_motion(motion, config.side, lengths, np.zeros(1), stance)
        hand = rest.points["hand"].p[0]
        outward = rest.frames["thorax"].R[0] @ np.array([0.0, 0.0, -1.0 if config.side == "left"
                                                         else 1.0])
        environment = replace(environment, disturbances=(Dipole(
            position_m=tuple(hand + 0.12 * outward), strength_ut=150.0, axis=(0.0, 1.0, 0.3),
            start_s=10.5 + offset if config.calibration else 0.0),))

    if config.start_disturbance_s is not None and config.nine_axis:
        environment = replace(environment, disturbances=(
            *environment.disturbances,
            *start_disturbances(motion, config, lengths, stance, rng)))

    streams: dict[str, SensorStream] = {}
    mounts: dict[str, Mount] = {}
    R_world_sensor: dict[str, np.ndarray] = {}
    for sensor in (s for s in SENSOR_NAMES if s in config.sensors):
        mount = random_mount(sensor, config, lengths, rng)
        t = sample_times(duration, config, rng)
        errors = replace(config.errors, gyro_bias=tuple(
            rng.uniform(-config.gyro_bias_max, config.gyro_bias_max, 3)))
        body = body_motion(motion, config.side, lengths, t, stance)
        late = (body_motion(motion, config.side, lengths, t - config.gyro_delay_s, stance)
                if config.gyro_delay_s else None)
        signals = synthesize_imu(body, sensor, mount, nine_axis=config.nine_axis,
                                 errors=errors, environment=environment, rng=rng,
                                 gyro_body=late)
        stamps = signals.t
        if config.pack_size > 1:  # each pack stamped with its first sample's time
            stamps = np.repeat(signals.t[::config.pack_size], config.pack_size)[:len(t)]
        streams[sensor] = SensorStream(t=stamps, acc=signals.acc, gyr=signals.gyr,
                                       mag=signals.mag)
        mounts[sensor] = mount
        R_world_sensor[sensor] = signals.R_world_sensor

    grid = np.arange(int(np.floor(duration * config.rate_hz)) + 1) / config.rate_hz
    angles = {k: (motion.joints[k].evaluate(grid)[0] if k in motion.joints
                  else np.zeros_like(grid)) for k in ANGLE_NAMES}
    pose = forward_kinematics(angles, config.side, lengths)
    down = np.array([0.0, -1.0, 0.0])
    angles[ELEVATION] = angle_between(pose.R_thorax["upper_arm"] @ down, down)
    excursions = {k: tuple(sorted(p.excursions, key=lambda e: e.up_s))
                  for k, p in motion.joints.items() if p.excursions}
    truth = Truth(t=grid, angles=angles, positions=pose.p_thorax, mounts=mounts,
                  R_world_sensor=R_world_sensor, excursions=excursions)

    calibration = ()
    if config.calibration:
        npose, tpose = pose_windows(config.npose_s)
        calibration = (Pose("npose", *npose), Pose("tpose", *tpose))
    points, points_frame = {}, None
    if config.wrist_points is not None:
        points, points_frame = wrist_points(
            WRIST_SOURCES[config.wrist_points], motion, config, lengths, stance, duration, rng)
    recording = Recording(
        side=config.side, sensors=streams, height_m=config.height_m,
        lengths=None if lengths == SegmentLengths.from_height(config.height_m) else lengths,
        calibration=calibration, rate_hz=config.rate_hz,
        metadata={"scenario": config.exercise, "simulator": "armtrack", "seed": str(config.seed),
                  **({GYRO_DELAY_KEY: repr(float(config.gyro_delay_s))}
                     if config.declare_gyro_delay else {})},
        points=points, points_frame=points_frame,
    )
    return Simulation(recording=recording, truth=truth)


def write_truth(truth: Truth, path) -> None:
    """Write the truth table as CSV (the columns of ``shared``'s ``*.truth.csv``), owner-only
    (0600) like the recording it describes."""
    import os

    columns, values = truth.table()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)  # an older file of that name keeps no wider mode
    with open(fd, "w", encoding="utf-8", newline="\n") as file:
        file.write(",".join(columns) + "\n")
        np.savetxt(file, values, delimiter=",", fmt="%.6f")
