"""The stream's position points (``docs/extensions/points.md``): the ``hello``'s ``points``
declaration and the ``points`` message, checked whole.

``hello`` may carry::

    "points": {"names": ["wrist"], "frame": "base", "thorax_yaw_deg": 30.0,
               "shoulder_m": [0.12, -0.18, 1.31], "latency_s": 0.06}

(``frame`` ``thorax`` or ``base``; ``thorax_yaw_deg`` and ``shoulder_m`` as in recordings;
``latency_s`` [s], 0–2, taken off every point's ``t`` — a camera that stamps frames on
arrival). Then ``{"type": "points", "seq": 7, "point": "wrist", "rows": [[t, x, y, z],
…]}`` (1–1000 rows, metres in the declared frame) shares ``seq`` with ``samples`` and
``mark``, is acked and resumed like them, and is stored as rows of the pseudo-sensor
``point:wrist`` (``[t, x, y, z]`` and six NaN, so the storage and its resume need nothing
new).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from armtrack.estimator.errors import InvalidArgument, InvalidRecording
from armtrack.estimator.recording.points import (
    POINT_NAMES,
    POINT_RANGE_M,
    POINTS_HEADER_KEYS,
    PointsFrame,
    frame_from_header,
)

#: A point's rows are stored under this prefix and its name: ``point:wrist``.
POINT_PREFIX = "point:"
#: Largest declared latency [s].
MAX_LATENCY_S = 2.0
MAX_ROWS = 1000


@dataclass(frozen=True)
class PointsDeclaration:
    """What ``hello`` says of its points: their ``names``, ``frame`` and ``latency_s``."""

    names: tuple[str, ...]
    frame: PointsFrame
    latency_s: float = 0.0

    def as_meta(self) -> dict[str, str]:
        """As a session's metadata: the recording header's lines of the frame."""
        return frame_to_meta(self.frame)


def frame_to_meta(frame: PointsFrame) -> dict[str, str]:
    """A points frame as a session's metadata: the keys and values of the recording
    header's lines (``points_frame``, ``points_thorax_yaw_deg``, ``points_shoulder_m``)."""
    return dict(line.split(": ", 1) for line in frame.header_lines())


def frame_from_meta(meta: dict[str, Any]) -> PointsFrame | None:
    """A session's points frame from its metadata (None without one, or a broken one)."""
    values = {key: (str(meta[key]), 0) for key in POINTS_HEADER_KEYS if key in meta}
    if "points_frame" not in values:
        return None
    try:
        return frame_from_header(values, 0)
    except InvalidRecording:
        return None


def check_declaration(value: Any) -> PointsDeclaration:
    """``hello``'s ``points``; raises ValueError with the reason."""
    if not isinstance(value, dict):
        raise ValueError("points must be an object: names, frame, and for a base frame "
                         "thorax_yaw_deg and shoulder_m")
    unknown = set(value) - {"names", "frame", "thorax_yaw_deg", "shoulder_m", "latency_s"}
    if unknown:
        raise ValueError(f"points: unknown field {sorted(unknown)[0]!r}")
    names = value.get("names")
    if (not isinstance(names, list) or not names or len(set(map(str, names))) != len(names)
            or not all(n in POINT_NAMES for n in names)):
        raise ValueError(f"points: names must list some of {', '.join(POINT_NAMES)} once each")
    yaw = value.get("thorax_yaw_deg")
    if yaw is not None and not _finite(yaw):
        raise ValueError("points: thorax_yaw_deg must be a number of degrees")
    shoulder = value.get("shoulder_m")
    if shoulder is not None and (not isinstance(shoulder, list) or len(shoulder) != 3
                                 or not all(_finite(v) for v in shoulder)):
        raise ValueError("points: shoulder_m must be [x, y, z] in metres")
    latency = value.get("latency_s", 0.0)
    if not (_finite(latency) and 0.0 <= latency <= MAX_LATENCY_S):
        raise ValueError(f"points: latency_s must be 0 to {MAX_LATENCY_S:g} s")
    try:
        frame = PointsFrame(value.get("frame"), None if yaw is None else float(yaw),
                            None if shoulder is None else tuple(float(v) for v in shoulder))
    except InvalidArgument as exc:
        raise ValueError(f"points: {exc}") from None
    return PointsDeclaration(tuple(names), frame, float(latency))


def check_points(message: dict[str, Any], declared: PointsDeclaration | None,
                 last_t: dict[str, float], t_offset: float = 0.0
                 ) -> tuple[str, np.ndarray]:
    """A ``points`` message: ``(stored sensor name, rows (n, 10))``, NaN-padded, with the
    declared latency taken off ``t`` and ``t_offset`` added. Raises ValueError with the
    reason (the caller refuses the message whole, naming its ``seq``)."""
    if declared is None:
        raise ValueError("points: hello declared no points (add 'points' to hello)")
    point = message.get("point")
    if point not in declared.names:
        raise ValueError(f"points: point {point!r} was not declared in hello "
                         f"({', '.join(declared.names)})")
    rows = message.get("rows")
    if not isinstance(rows, list) or not 1 <= len(rows) <= MAX_ROWS:
        raise ValueError(f"points: rows must be a list of 1 to {MAX_ROWS} rows")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 4 or not all(_finite(v) for v in row):
            raise ValueError(f"points: row {i} must be [t, x, y, z], four finite numbers")
    data = np.full((len(rows), 10), np.nan)
    data[:, :4] = np.array(rows, dtype=np.float64)
    shift = t_offset - declared.latency_s
    if shift:
        data[:, 0] += shift
    far = np.flatnonzero(np.linalg.norm(data[:, 1:4], axis=1) > POINT_RANGE_M)
    if len(far):
        raise ValueError(f"points: row {far[0]} is more than {POINT_RANGE_M:g} m from the "
                         "frame's origin")
    t = data[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        raise ValueError(f"points: t goes backwards at row {back[0] + 1}")
    name = POINT_PREFIX + point
    previous = last_t.get(name)
    if previous is not None and t[0] < previous:
        raise ValueError(f"points: t goes backwards for point {point} ({float(t[0])!r} "
                         f"after {float(previous)!r})")
    return name, data


def _finite(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False
