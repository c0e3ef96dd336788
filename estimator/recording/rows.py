"""Data rows: the rules every row obeys, checked line by line (the slow path and the
wording of every row error) or vectorised over parsed columns (the fast path).

Rules, checked in this order within a row:
1. the line ends in LF or CRLF (no other carriage return) and is UTF-8;
2. it is not blank (blank lines are allowed only at the end of the file) and not a
   header line (``#`` lines come before the column line);
3. it has 11 comma-separated fields;
4. ``t`` is a finite plain decimal; ``sensor`` is one of ``SENSOR_NAMES``;
5. ``ax … gz`` are finite plain decimals; ``mx my mz`` are all empty (6-axis) or all
   finite plain decimals;
6. the norms of a, g and m are within the physical range (``rules.LIMITS``);
7. a sensor is 6-axis in every row or 9-axis in every row;
8. ``t`` does not go backwards for the row's sensor;
9. ``|t| ≤ T_LIMIT_S`` and ``t`` is at most ``STEP_LIMIT_S`` after the sensor's previous
   ``t`` (``docs/extensions/time-bounds.md``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..body import SENSOR_NAMES
from ..errors import InvalidRecording
from .model import SensorStream
from .rules import (
    COLUMN_LINE,
    NUMERIC,
    STEP_LIMIT_S,
    T_LIMIT_S,
    backwards_message,
    beyond_range,
    decode_line,
    parse_number,
    range_message,
    step_beyond_message,
    time_beyond_message,
)

_SENSOR_INDEX = {name: k for k, name in enumerate(SENSOR_NAMES)}
_QUANTITIES = (("acc", slice(1, 4)), ("gyr", slice(4, 7)), ("mag", slice(7, 10)))


class Rows(NamedTuple):
    """Parsed data rows.

    codes: index into ``SENSOR_NAMES`` per row, -1 for an unknown sensor, shape (N,).
    values: the columns ``t ax ay az gx gy gz mx my mz``, NaN where empty, shape (10, N)
        (column-major, so each column is contiguous).
    mag_null: which of ``mx my mz`` were empty, shape (3, N).
    """

    codes: np.ndarray
    values: np.ndarray
    mag_null: np.ndarray


class RowChecker:
    """Checks rows one at a time, keeping per sensor its last ``t`` and its 6/9-axis kind."""

    def __init__(self) -> None:
        self._last_t: dict[str, float] = {}
        self._kind: dict[str, tuple[bool, int]] = {}

    def seed(self, sensor: str, last_t: float, nine_axis: bool, first_line: int) -> None:
        """Start from a sensor's state after earlier (valid) rows."""
        self._last_t[sensor] = last_t
        self._kind[sensor] = (nine_axis, first_line)

    def check(self, raw: bytes, line: int) -> tuple[int, list[float]]:
        """Sensor index and the 10 values of one row (mag NaN when empty); raises
        InvalidRecording naming ``line`` and the first rule the row breaks."""
        text = decode_line(raw, line)
        if not text:
            raise InvalidRecording("blank line (blank lines are allowed only at the end)", line)
        if text.startswith("#"):
            raise InvalidRecording("header line after the column line", line)
        fields = text.split(",")
        if len(fields) != 11:
            raise InvalidRecording(
                f"expected 11 fields ({COLUMN_LINE}), got {len(fields)}", line
            )
        t = self._number(fields[0], "t", line)
        sensor = fields[1]
        if sensor not in _SENSOR_INDEX:
            raise InvalidRecording(
                f"unknown sensor {sensor!r} (expected one of {', '.join(SENSOR_NAMES)})", line
            )
        values = [t]
        values += [self._number(f, c, line) for f, c in zip(fields[2:8], NUMERIC[1:7], strict=True)]
        mag = fields[8:]
        nine_axis = any(mag)
        if nine_axis:
            values += [self._number(f, c, line) for f, c in zip(mag, NUMERIC[7:], strict=True)]
        else:
            values += [float("nan")] * 3
        for quantity, columns in _QUANTITIES:
            vector = values[columns]
            if (quantity != "mag" or nine_axis) and beyond_range(quantity, *vector):
                raise InvalidRecording(range_message(quantity, sensor, vector), line)
        kind, first = self._kind.setdefault(sensor, (nine_axis, line))
        if kind != nine_axis:
            now, was = ("magnetometer", "6-axis") if nine_axis else ("no magnetometer", "9-axis")
            raise InvalidRecording(
                f"sensor {sensor} has {now} values here but is {was} from line {first} "
                "(a sensor is 6-axis or 9-axis throughout)",
                line,
            )
        last = self._last_t.get(sensor)
        if last is not None and t < last:
            raise InvalidRecording(backwards_message(sensor, t, last), line)
        if abs(t) > T_LIMIT_S:
            raise InvalidRecording(time_beyond_message("t", t), line)
        if last is not None and t - last > STEP_LIMIT_S:
            raise InvalidRecording(step_beyond_message(sensor, t, last), line)
        self._last_t[sensor] = t
        return _SENSOR_INDEX[sensor], values

    @staticmethod
    def _number(text: str, column: str, line: int) -> float:
        if not text:
            if column in ("mx", "my", "mz"):
                raise InvalidRecording(
                    "mx, my, mz must be all empty (6-axis) or all given", line
                )
            raise InvalidRecording(f"missing value for {column}", line)
        return parse_number(text, column, line)


def parse_rows_slow(lines: list[bytes], first_line: int, checker: RowChecker | None = None) -> Rows:
    """Check and parse data rows one by one, from ``checker``'s state (default: none yet)."""
    checker = checker or RowChecker()
    codes = np.empty(len(lines), dtype=np.int8)
    values = np.empty((len(lines), 10))
    for i, raw in enumerate(lines):
        codes[i], values[i] = checker.check(raw, first_line + i)
    values = np.ascontiguousarray(values.T)
    return Rows(codes, values, np.isnan(values[7:]))


def first_bad_row(rows: Rows) -> int | None:
    """Index of the first row that breaks a rule, by vectorised checks, or None.

    Each check flags row i correctly whenever every row before i is valid, so the first
    flagged row is the first bad one; :func:`explain` then words its error."""
    codes, values, mag_null = rows
    bad = codes < 0
    for j in range(7):
        bad |= ~np.isfinite(values[j])
    some = mag_null[0] | mag_null[1] | mag_null[2]
    every = mag_null[0] & mag_null[1] & mag_null[2]
    bad |= some & ~every
    for j in range(7, 10):
        bad |= ~(np.isfinite(values[j]) | mag_null[j - 7])
    with np.errstate(invalid="ignore", over="ignore"):
        for quantity, columns in _QUANTITIES:
            bad |= beyond_range(quantity, *values[columns])
    for idx in sensor_rows(codes):
        if idx.size:
            bad[idx] |= every[idx] != every[idx[0]]
            t = values[0, idx]
            with np.errstate(over="ignore", invalid="ignore"):
                bad[idx[1:]] |= (t[1:] < t[:-1]) | (t[1:] - t[:-1] > STEP_LIMIT_S)
    with np.errstate(invalid="ignore"):
        bad |= np.abs(values[0]) > T_LIMIT_S
    flagged = np.flatnonzero(bad)
    return int(flagged[0]) if flagged.size else None


def explain(rows: Rows, index: int, raw: bytes, line: int) -> InvalidRecording:
    """The error for row ``index`` (text ``raw`` on ``line``), flagged by first_bad_row."""
    try:
        checker_after(rows, index, line - index).check(raw, line)
    except InvalidRecording as exc:
        return exc
    raise AssertionError(f"line {line} was flagged by the vectorised checks but passes")


def checker_after(rows: Rows, index: int, first_line: int) -> RowChecker:
    """A row checker in the state that the (valid) rows before ``index`` leave; row 0 is
    on ``first_line``."""
    checker = RowChecker()
    for name, idx in zip(SENSOR_NAMES, sensor_rows(rows.codes[:index]), strict=True):
        if idx.size:
            first, last = int(idx[0]), int(idx[-1])
            nine_axis = not bool(rows.mag_null[0, first])
            checker.seed(name, float(rows.values[0, last]), nine_axis, first_line + first)
    return checker


def concat(parts: list[Rows]) -> Rows:
    """Rows of consecutive pieces as one."""
    if len(parts) == 1:
        return parts[0]
    return Rows(
        np.concatenate([p.codes for p in parts]),
        np.concatenate([p.values for p in parts], axis=1),
        np.concatenate([p.mag_null for p in parts], axis=1),
    )


def streams(rows: Rows) -> dict[str, SensorStream]:
    """Per-sensor streams from valid rows, in ``SENSOR_NAMES`` order."""
    codes, values, mag_null = rows
    out = {}
    for name, idx in zip(SENSOR_NAMES, sensor_rows(codes), strict=True):
        if idx.size:
            v = values[:, idx].T  # (n, 10); each slice below is copied into its own array
            out[name] = SensorStream(
                t=v[:, 0].copy(),
                acc=v[:, 1:4].copy(),
                gyr=v[:, 4:7].copy(),
                mag=None if mag_null[0, idx[0]] else v[:, 7:].copy(),
            )
    return out


def sensor_rows(codes: np.ndarray) -> list[np.ndarray]:
    """Row indices of each sensor of ``SENSOR_NAMES``, in file order."""
    order = np.argsort(codes, kind="stable")
    bounds = np.searchsorted(codes[order], np.arange(len(SENSOR_NAMES) + 1))
    return [order[bounds[k] : bounds[k + 1]] for k in range(len(SENSOR_NAMES))]
