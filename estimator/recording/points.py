"""Position points beside the IMUs (``docs/extensions/points.md``, recording version 2).

An end-effector rehabilitation robot (its handle) or a camera gives the **wrist** position
over time. In a recording they follow the IMU rows as a second section::

    t,point,x,y,z
    0.01,wrist,0.212,-0.441,0.318

``t`` [s] on the recording's clock, stamped at capture; ``x y z`` [m] in the points frame
the header declares:

- ``points_frame: thorax`` — the thorax frame of ``kinematics.md`` (ISB: X anterior,
  Y superior, Z right; origin at the sternal notch);
- ``points_frame: base`` — a z-up frame of the robot or camera (gravity along −z), with
  ``points_thorax_yaw_deg`` (the direction the patient faces: the thorax's X axis, in
  degrees counter-clockwise from the base's +x about +z) and ``points_shoulder_m`` (the
  shoulder centre in the base frame, from the set-up step: the handle held at the
  shoulder, or measured).

``points_shoulder_m: x y z`` may also be given with the thorax frame (a measured shoulder);
without it the shoulder is the arm model's ``(0, 0, ±l_c)``.

Units: time [s], positions [m], angles [deg] in the header.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import InvalidArgument, InvalidRecording, InvalidShape
from ..rotations import elemental
from .rules import parse_number

#: Point names a recording or stream may carry.
POINT_NAMES: tuple[str, ...] = ("wrist",)
#: The points section's column line, exactly.
POINTS_COLUMN_LINE = "t,point,x,y,z"
#: Largest distance of a point from its frame's origin [m]: a robot's or a room's reach.
POINT_RANGE_M = 10.0
#: Header keys of the extension.
POINTS_HEADER_KEYS: tuple[str, ...] = (
    "points_frame", "points_thorax_yaw_deg", "points_shoulder_m")

#: Thorax axes in a z-up frame when the subject faces its +x: X → +x, Y → +z, Z → −y.
R_BASE_THORAX_FACING_X = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class PointStream:
    """One point's positions: ``t`` [s] (N,), non-decreasing; ``p`` [m] (N, 3) in the
    recording's points frame."""

    t: np.ndarray
    p: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        p = np.asarray(self.p, dtype=np.float64)
        if t.ndim != 1 or p.shape != (len(t), 3):
            raise InvalidShape(f"a point stream needs t (N,) and p (N, 3), got {t.shape} and "
                               f"{p.shape}")
        for name, array in (("t", t), ("p", p)):
            view = array.view()
            view.flags.writeable = False
            object.__setattr__(self, name, view)

    def __len__(self) -> int:
        return len(self.t)


@dataclass(frozen=True)
class PointsFrame:
    """Where the points are given: ``kind`` ``thorax`` or ``base`` (z up); for ``base``
    the thorax's heading ``thorax_yaw_deg`` [deg] about +z; ``shoulder_m`` [m] the shoulder
    centre in that frame (required for ``base``, optional for ``thorax``)."""

    kind: Literal["thorax", "base"] = "thorax"
    thorax_yaw_deg: float | None = None
    shoulder_m: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("thorax", "base"):
            raise InvalidArgument(f"points frame must be thorax or base, got {self.kind!r}")
        if self.kind == "base" and (self.thorax_yaw_deg is None or self.shoulder_m is None):
            raise InvalidArgument("a base points frame needs the thorax's yaw "
                                  "(points_thorax_yaw_deg) and the shoulder "
                                  "(points_shoulder_m) in it")
        if self.kind == "thorax" and self.thorax_yaw_deg is not None:
            raise InvalidArgument("points_thorax_yaw_deg belongs to a base points frame")
        if self.thorax_yaw_deg is not None and not math.isfinite(self.thorax_yaw_deg):
            raise InvalidArgument("points_thorax_yaw_deg must be finite")
        if self.shoulder_m is not None:
            s = tuple(float(v) for v in self.shoulder_m)
            if len(s) != 3 or not all(math.isfinite(v) for v in s) \
                    or math.hypot(*s) > POINT_RANGE_M:
                raise InvalidArgument(f"points_shoulder_m must be three finite metres within "
                                      f"{POINT_RANGE_M:g} m, got {self.shoulder_m!r}")
            object.__setattr__(self, "shoulder_m", s)

    def to_thorax(self, shoulder_thorax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R, o)`` with ``p_thorax = R @ (p - o)`` for a point ``p`` of this frame [m];
        ``shoulder_thorax`` is the arm model's shoulder centre in the thorax frame."""
        if self.kind == "thorax":
            return np.eye(3), np.zeros(3)
        R_base_thorax = elemental("z", np.deg2rad(self.thorax_yaw_deg)) @ R_BASE_THORAX_FACING_X
        origin = np.asarray(self.shoulder_m) - R_base_thorax @ shoulder_thorax
        return R_base_thorax.T, origin

    def shoulder_in_thorax(self, model_shoulder: np.ndarray) -> np.ndarray:
        """The shoulder centre [m] in the thorax frame: measured where given, else the
        model's."""
        if self.shoulder_m is None or self.kind == "base":
            return np.asarray(model_shoulder, dtype=float)
        return np.asarray(self.shoulder_m)

    def header_lines(self) -> list[str]:
        """The header lines (without ``# ``) that declare this frame."""
        lines = [f"points_frame: {self.kind}"]
        if self.thorax_yaw_deg is not None:
            lines.append(f"points_thorax_yaw_deg: {float(self.thorax_yaw_deg)!r}")
        if self.shoulder_m is not None:
            lines.append("points_shoulder_m: " + " ".join(repr(float(v)) for v in self.shoulder_m))
        return lines


def frame_from_header(values: dict[str, tuple[str, int]], column_line: int) -> PointsFrame:
    """The points frame from the extension's header values ``{key: (text, line)}``."""
    if "points_frame" not in values:
        raise InvalidRecording("a recording with points needs the header 'points_frame' "
                               "(thorax or base)", column_line)
    kind, line = values["points_frame"]
    yaw = shoulder = None
    if "points_thorax_yaw_deg" in values:
        text, yaw_line = values["points_thorax_yaw_deg"]
        yaw = parse_number(text, "points_thorax_yaw_deg", yaw_line)
    if "points_shoulder_m" in values:
        text, s_line = values["points_shoulder_m"]
        parts = text.split()
        if len(parts) != 3:
            raise InvalidRecording(f"points_shoulder_m must be 'X Y Z' in metres, got {text!r}",
                                   s_line)
        shoulder = tuple(parse_number(v, "points_shoulder_m", s_line) for v in parts)
    try:
        return PointsFrame(kind, yaw, shoulder)  # type: ignore[arg-type]
    except InvalidArgument as exc:
        raise InvalidRecording(str(exc), line) from None


def parse_points(text_lines: list[bytes], first_line: int) -> dict[str, PointStream]:
    """The point rows after the ``t,point,x,y,z`` line; ``first_line`` is the first row's
    line number. Refuses (InvalidRecording naming the line) a malformed row, an unknown
    point, a non-finite or out-of-range position, or time going backwards per point."""
    t_of: dict[str, list[float]] = {}
    p_of: dict[str, list[tuple[float, float, float]]] = {}
    for i, raw in enumerate(text_lines):
        line = first_line + i
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InvalidRecording("line is not valid UTF-8", line) from None
        if text.endswith("\r"):
            text = text[:-1]
        if not text:
            raise InvalidRecording("blank line (blank lines are allowed only at the end)", line)
        fields = text.split(",")
        if len(fields) != 5:
            raise InvalidRecording(f"expected 5 fields ({POINTS_COLUMN_LINE}), got "
                                   f"{len(fields)}", line)
        name = fields[1]
        if name not in POINT_NAMES:
            raise InvalidRecording(f"unknown point {name!r} (expected one of "
                                   f"{', '.join(POINT_NAMES)})", line)
        t = parse_number(fields[0], "t", line)
        xyz = tuple(parse_number(v, c, line) for v, c in zip(fields[2:], "xyz", strict=True))
        if math.hypot(*xyz) > POINT_RANGE_M:
            raise InvalidRecording(f"point {name} is {math.hypot(*xyz):.3g} m from the frame's "
                                   f"origin (at most {POINT_RANGE_M:g} m)", line)
        times = t_of.setdefault(name, [])
        if times and t < times[-1]:
            raise InvalidRecording(f"t goes backwards for point {name} ({t!r} after "
                                   f"{times[-1]!r})", line)
        times.append(t)
        p_of.setdefault(name, []).append(xyz)  # type: ignore[arg-type]
    return {name: PointStream(np.array(t_of[name]), np.array(p_of[name]).reshape(-1, 3))
            for name in POINT_NAMES if name in t_of}


def check_points(points: dict[str, PointStream]) -> None:
    """Refuse (InvalidRecording, no line) points a file could not carry."""
    for name, stream in points.items():
        if name not in POINT_NAMES:
            raise InvalidRecording(f"unknown point {name!r}")
        if not len(stream):
            raise InvalidRecording(f"point {name} has no samples")
        if not (np.isfinite(stream.t).all() and np.isfinite(stream.p).all()):
            raise InvalidRecording(f"point {name} has a value that is not finite")
        if (np.linalg.norm(stream.p, axis=1) > POINT_RANGE_M).any():
            raise InvalidRecording(f"point {name} is beyond {POINT_RANGE_M:g} m")
        if (np.diff(stream.t) < 0).any():
            raise InvalidRecording(f"t goes backwards for point {name}")


def format_points(points: dict[str, PointStream]) -> bytes:
    """The points section: its column line and rows merged by time (shortest round-trip
    text, so the file reads back as the same float64 numbers)."""
    names, ts, ps = [], [], []
    for name in POINT_NAMES:
        if name in points:
            stream = points[name]
            names += [name] * len(stream)
            ts.append(stream.t)
            ps.append(stream.p)
    t = np.concatenate(ts)
    p = np.concatenate(ps)
    order = np.argsort(t, kind="stable")
    tl, pl = t[order].tolist(), p[order].tolist()  # Python floats: repr round-trips
    rows = [f"{ti!r},{names[i]},{x!r},{y!r},{z!r}\n"
            for ti, i, (x, y, z) in zip(tl, order.tolist(), pl, strict=True)]
    return (POINTS_COLUMN_LINE + "\n" + "".join(rows)).encode("utf-8")
