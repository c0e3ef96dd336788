"""What a recording holds (``docs/spec/recording.md``): per-sensor sample streams, body size,
calibration poses, exercise marks and free-form metadata.

Units: time [s], specific force [m/s^2], angular rate [rad/s], magnetic field [µT],
lengths and height [m], rate [Hz].

The classes check their own structure when built (shapes, names, label grammar); the
sample values themselves (finite, within physical range, time order) are the file's
rules and are checked by the reader and, before anything is written, by the writer
(:func:`armtrack.estimator.recording.check_recording`). Arrays are stored as read-only
float64 views so a frozen object stays frozen.
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..body import SENSOR_NAMES, SIDES, SegmentLengths
from ..errors import InvalidArgument, InvalidShape
from .points import POINT_NAMES, POINTS_HEADER_KEYS, PointsFrame, PointStream
from .rules import T_LIMIT_S, time_beyond_message

#: The format versions this code reads and writes: 1, and 2 = 1 with the points extension
#: (``docs/extensions/points.md``), written only for a recording that has a points frame.
FORMAT_VERSION = 1
POINTS_VERSION = 2
SUPPORTED_VERSIONS: tuple[int, ...] = (1, 2)

PoseName = Literal["npose", "tpose"]
POSE_NAMES: tuple[str, ...] = ("npose", "tpose")

#: Header keys with a meaning, in the order the writer puts them (spec's table order).
HEADER_KEYS: tuple[str, ...] = (
    "armtrack-recording", "side", "height_m", "lengths_m", "calibration", "marks", "rate_hz",
)

#: The header of the gyro-delay extension (``docs/extensions/gyro-delay.md``): how far the
#: kit's gyroscopes lag its accelerometers [s]. Kept in ``Recording.metadata`` as written
#: (so every writer carries it back), checked wherever metadata is.
GYRO_DELAY_KEY = "gyro_delay_s"


def _gyro_delay(value: str) -> float:
    """The value of a ``gyro_delay_s`` header as seconds, or InvalidArgument."""
    from ..orientation.qcf import check_gyro_delay
    from .rules import NUMBER
    if not NUMBER.fullmatch(value):
        raise InvalidArgument(f"gyro_delay_s must be a plain decimal number of seconds, "
                              f"got {value!r}")
    return check_gyro_delay(float(value))


#: A header key: what may stand before the ``:`` of ``# key: value``.
KEY_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")

#: A mark label (``docs/spec/ingest.md``): ``npose``, ``tpose``, ``exercise:<name>``, each
#: optionally prefixed by ``end:``. An exercise name is letters, digits, ``_ . -``.
LABEL_PATTERN = re.compile(r"(?:end:)?(?:npose|tpose|exercise:[A-Za-z0-9_.\-]+)")


def _is_finite(value: object) -> bool:
    return isinstance(value, numbers.Real) and math.isfinite(value)


def _frozen_array(value, name: str, width: int | None) -> np.ndarray:
    """``value`` as a read-only float64 view of shape (N,) or (N, width)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidShape(f"{name} must be an array of numbers: {exc}") from None
    expected = 1 if width is None else 2
    if array.ndim != expected or (width is not None and array.shape[1] != width):
        want = "(N,)" if width is None else f"(N, {width})"
        raise InvalidShape(f"{name} must have shape {want}, got {array.shape}")
    view = array.view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True)
class Pose:
    """A still calibration period: ``name`` (``npose`` or ``tpose``) from ``start`` to
    ``end`` [s] on the recording's clock."""

    name: PoseName
    start: float
    end: float

    def __post_init__(self) -> None:
        if self.name not in POSE_NAMES:
            raise InvalidArgument(f"pose name must be npose or tpose, got {self.name!r}")
        for what in ("start", "end"):
            value = getattr(self, what)
            if not _is_finite(value):
                raise InvalidArgument(f"{self.name} {what} must be a finite time, got {value!r}")
            if abs(float(value)) > T_LIMIT_S:
                raise InvalidArgument(time_beyond_message(f"{self.name} {what}", value))
            object.__setattr__(self, what, float(value))
        if not self.start < self.end:
            raise InvalidArgument(
                f"{self.name} must start before it ends, got {self.start!r} to {self.end!r}"
            )


@dataclass(frozen=True)
class Mark:
    """A mark at time ``t`` [s]: ``npose``, ``tpose`` or ``exercise:<name>`` begins a
    period, ``end:<label>`` ends it (``docs/spec/ingest.md``)."""

    t: float
    label: str

    def __post_init__(self) -> None:
        if not _is_finite(self.t):
            raise InvalidArgument(f"mark time must be finite, got {self.t!r}")
        if abs(float(self.t)) > T_LIMIT_S:
            raise InvalidArgument(time_beyond_message("mark time", self.t))
        object.__setattr__(self, "t", float(self.t))
        if not isinstance(self.label, str) or not LABEL_PATTERN.fullmatch(self.label):
            raise InvalidArgument(
                f"mark label must be npose, tpose, exercise:<name> or end:<label>, "
                f"got {self.label!r}"
            )


@dataclass(frozen=True, eq=False)
class SensorStream:
    """One sensor's samples, in its own frame.

    t: sample times [s], shape (N,), non-decreasing.
    acc: specific force [m/s^2], shape (N, 3); at rest the axis pointing up reads +9.81.
    gyr: angular rate [rad/s], shape (N, 3).
    mag: magnetic field [µT], shape (N, 3), or None for a 6-axis sensor.
    """

    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _frozen_array(self.t, "t", None))
        n = len(self.t)
        for name in ("acc", "gyr", "mag"):
            value = getattr(self, name)
            if value is None and name == "mag":
                continue
            array = _frozen_array(value, name, 3)
            if len(array) != n:
                raise InvalidShape(f"{name} must have {n} rows like t, got {len(array)}")
            object.__setattr__(self, name, array)

    @property
    def nine_axis(self) -> bool:
        """True when the sensor has a magnetometer."""
        return self.mag is not None

    def __len__(self) -> int:
        return len(self.t)


@dataclass(frozen=True, eq=False)
class Recording:
    """One IMU recording of one arm (``docs/spec/recording.md``, version 1).

    side: ``right`` or ``left``.
    sensors: streams by sensor name; keys are kept in ``SENSOR_NAMES`` order.
    height_m: body height [m], or None when ``lengths`` are given (at least one is).
    lengths: measured segment lengths [m], or None; they win over ``height_m``.
    calibration: still calibration periods, in file order.
    marks: exercise and pose marks, in file order.
    rate_hz: nominal sample rate [Hz], or None; informative only.
    metadata: the header's other ``key: value`` lines, in file order.
    points: position points by name (``wrist``), in ``points_frame`` (version 2 only).
    points_frame: where the points are given, or None (then the file is version 1).
    """

    side: Literal["right", "left"]
    sensors: dict[str, SensorStream]
    height_m: float | None = None
    lengths: SegmentLengths | None = None
    calibration: tuple[Pose, ...] = ()
    marks: tuple[Mark, ...] = ()
    rate_hz: float | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    points: dict[str, PointStream] = field(default_factory=dict)
    points_frame: PointsFrame | None = None

    @property
    def version(self) -> int:
        """The file format version this recording is written in."""
        return POINTS_VERSION if self.points_frame is not None else FORMAT_VERSION

    def __post_init__(self) -> None:
        if self.side not in SIDES:
            raise InvalidArgument(f"side must be right or left, got {self.side!r}")
        unknown = [name for name in self.sensors if name not in SENSOR_NAMES]
        if unknown:
            raise InvalidArgument(
                f"unknown sensor {unknown[0]!r} (expected one of {', '.join(SENSOR_NAMES)})"
            )
        for name, stream in self.sensors.items():
            if not isinstance(stream, SensorStream):
                raise InvalidArgument(f"sensor {name} must be a SensorStream")
        ordered = {name: self.sensors[name] for name in SENSOR_NAMES if name in self.sensors}
        object.__setattr__(self, "sensors", ordered)
        if self.height_m is None and self.lengths is None:
            raise InvalidArgument("a recording needs height_m or lengths")
        if self.height_m is not None:
            if not _is_finite(self.height_m):
                raise InvalidArgument(f"height_m must be a finite number, got {self.height_m!r}")
            object.__setattr__(self, "height_m", float(self.height_m))
            SegmentLengths.from_height(self.height_m)  # refuses implausible heights
        if self.lengths is not None and not isinstance(self.lengths, SegmentLengths):
            raise InvalidArgument("lengths must be SegmentLengths")
        object.__setattr__(self, "calibration", tuple(self.calibration))
        object.__setattr__(self, "marks", tuple(self.marks))
        if not all(isinstance(p, Pose) for p in self.calibration):
            raise InvalidArgument("calibration must hold Pose objects")
        if not all(isinstance(m, Mark) for m in self.marks):
            raise InvalidArgument("marks must hold Mark objects")
        if self.rate_hz is not None:
            if not (_is_finite(self.rate_hz) and self.rate_hz > 0):
                raise InvalidArgument(f"rate_hz must be positive and finite, got {self.rate_hz!r}")
            object.__setattr__(self, "rate_hz", float(self.rate_hz))
        object.__setattr__(self, "metadata", dict(self.metadata))
        for key, value in self.metadata.items():
            check_metadata(key, value)
        self._check_points()

    def _check_points(self) -> None:
        points = {n: self.points[n] for n in POINT_NAMES if n in self.points}
        unknown = set(self.points) - set(points)
        if unknown:
            raise InvalidArgument(f"unknown point {sorted(unknown)[0]!r} (expected one of "
                                  f"{', '.join(POINT_NAMES)})")
        if not all(isinstance(s, PointStream) for s in points.values()):
            raise InvalidArgument("points must hold PointStream objects")
        if points and self.points_frame is None:
            raise InvalidArgument("a recording with points needs their points_frame")
        if self.points_frame is not None:
            if not isinstance(self.points_frame, PointsFrame):
                raise InvalidArgument("points_frame must be a PointsFrame")
            clash = [k for k in self.metadata if k in POINTS_HEADER_KEYS]
            if clash:
                raise InvalidArgument(f"metadata key {clash[0]!r} is a header field of the "
                                      "points extension")
        object.__setattr__(self, "points", points)

    def segment_lengths(self) -> SegmentLengths:
        """Segment lengths [m]: the measured ones if given, else from body height."""
        if self.lengths is not None:
            return self.lengths
        assert self.height_m is not None  # __post_init__ requires one of them
        return SegmentLengths.from_height(self.height_m)

    @property
    def gyro_delay_s(self) -> float:
        """How far the kit's gyroscopes lag its accelerometers [s], from the header
        ``gyro_delay_s`` (``docs/extensions/gyro-delay.md``; kept as metadata so that every
        writer carries it back); 0 when the file does not declare one."""
        value = self.metadata.get(GYRO_DELAY_KEY)
        return 0.0 if value is None else _gyro_delay(value)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample over all sensors [s]; 0 without samples."""
        starts = [s.t[0] for s in self.sensors.values() if len(s)]
        ends = [s.t[-1] for s in self.sensors.values() if len(s)]
        return float(max(ends) - min(starts)) if starts else 0.0


def check_metadata(key: object, value: object) -> None:
    """Refuse a metadata entry that a header line could not carry back unchanged."""
    if not isinstance(key, str) or not KEY_PATTERN.fullmatch(key):
        raise InvalidArgument(
            f"metadata key must be letters, digits, '_', '.', '-' (not first), got {key!r}"
        )
    if key in HEADER_KEYS:
        raise InvalidArgument(f"metadata key {key!r} is a header field of its own")
    if not isinstance(value, str) or value != value.strip() or "\n" in value or "\r" in value:
        raise InvalidArgument(
            f"metadata {key} must be one line of text without surrounding spaces, got {value!r}"
        )
    if key == GYRO_DELAY_KEY:
        _gyro_delay(value)
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise InvalidArgument(f"metadata {key} is not encodable as UTF-8: {value!r}") from None
