"""Messages of the stream protocol, version 1 (``docs/spec/ingest.md``), checked whole: a
message is either accepted as a whole or refused with a reason naming what is wrong.

Rows are ``[t, ax, ay, az, gx, gy, gz, mx, my, mz]`` in the units of ``recording.md``
(s, m/s², rad/s, µT); on a 6-axis sensor ``mx my mz`` are ``null``.

Extension (the spec is silent on it): ``hello`` may carry ``"session": <id>`` with
``"resume": null`` to start a *new stream in the same session*, for a kit whose clock
jumped backwards (its samples are refused: ``t goes backwards``) or that lost its stream
id. See :mod:`armtrack.server.ingest.endpoint`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from itertools import chain
from typing import Any, Literal

import msgspec
import numpy as np
import orjson
from armtrack.estimator.body import SENSOR_NAMES
from armtrack.estimator.jit import compiler
from armtrack.estimator.orientation.qcf import GYRO_DELAY_MAX_S
from armtrack.estimator.recording.model import LABEL_PATTERN
from armtrack.estimator.recording.rules import (
    LIMITS,
    STEP_LIMIT_S,
    T_LIMIT_S,
    backwards_message,
    beyond_range,
    step_beyond_message,
    time_beyond_message,
)

from ..plain_text import text_problem
from . import points as _points
from .points import PointsDeclaration, check_declaration

PROTOCOL_VERSION = 1
#: ``hello``'s optional ``extensions``: at most this many ``name/version`` strings.
MAX_EXTENSIONS = 16
EXTENSION_PATTERN = re.compile(r"[a-z][a-z0-9_-]{0,39}/[1-9][0-9]{0,3}")
MAX_ROWS = 1000
ROW_WIDTH = 10
#: Longest mark label [characters] (``exercise:`` and a catalogue name is ~30): every
#: feedback stream keeps the marks it saw, and the session pages show them.
MARK_LABEL_MAX = 100

#: Close codes of the spec.
CLOSE_BAD_TOKEN = 4401
CLOSE_BAD_PROTOCOL = 4400
CLOSE_TOO_BIG = 1009
CLOSE_TOO_MANY_ERRORS = 4429

#: Most bytes of a close frame's reason (RFC 6455: 125 of payload, 2 taken by the code).
CLOSE_REASON_BYTES = 123
#: A close's reason when the whole explanation (the ``error`` message sent just before
#: the close) is longer than a close frame holds: a short, whole sentence by close code.
SHORT_CLOSE_REASONS: dict[int, str] = {
    CLOSE_BAD_PROTOCOL: "refused: the error message sent just before this close says why",
    CLOSE_TOO_MANY_ERRORS: "refused for now: the error message sent just before this close "
                           "says why",
}
#: The same for any other close code.
SHORT_CLOSE_REASON = "closed: the error message sent just before this close says why"


def close_reason(reason: str, code: int) -> str:
    """``reason`` when it fits a close frame (``CLOSE_REASON_BYTES`` of UTF-8), else the
    code's short sentence: never a sentence cut short, and never a frame too long to send
    (a kit echoing wide characters in a refused value made one: it saw 1006, not 4400)."""
    if len(reason.encode("utf-8")) <= CLOSE_REASON_BYTES:
        return reason
    return SHORT_CLOSE_REASONS.get(code, SHORT_CLOSE_REASON)


#: The words ending the ``error`` of a message refused because its session is full
#: (``ARMTRACK_MAX_SESSION_SAMPLES``): the kit starts a new session with it and the rest.
SESSION_FULL = "(ARMTRACK_MAX_SESSION_SAMPLES): start a new session"


class Refused(Exception):
    """A message refused whole. ``seq`` when it carried a valid one; ``close_code`` when
    the error ends the connection; ``counted``: whether it counts toward the kit's refused
    messages (``ARMTRACK_REFUSED_LIMIT``: its own bad data)."""

    def __init__(self, reason: str, seq: int | None = None, close_code: int | None = None,
                 extra: dict | None = None, counted: bool = True):
        super().__init__(reason)
        self.reason = reason
        self.seq = seq
        self.close_code = close_code
        #: more fields of the ``error`` message (``next_seq`` of a closed session's stream)
        self.extra = extra or {}
        self.counted = counted


@dataclass(frozen=True)
class Hello:
    device: str
    side: str
    sensors: tuple[str, ...]
    rate_hz: float | None
    nine_axis: bool
    resume: str | None
    #: extension: continue this (interrupted or live) session of the patient in a new stream
    session: int | None = None
    #: extension (docs/extensions/points.md): the position points the kit sends
    points: PointsDeclaration | None = None
    #: extension (``docs/extensions/README.md``): the versioned extensions the kit speaks,
    #: as ``name/version`` (``feedback/1``); the server answers those it speaks in ``ready``
    extensions: tuple[str, ...] = ()
    #: extension (docs/extensions/gyro-delay.md): how far the kit's gyroscopes lag its
    #: accelerometers [s]; None: not declared (in step)
    gyro_delay_s: float | None = None


# the messages' records are plain slotted classes, not frozen ones: a frozen dataclass's
# __init__ goes through object.__setattr__, and there is one per kit message
@dataclass(slots=True)
class Samples:
    seq: int
    sensor: str
    rows: np.ndarray  # (n, 10) float64, NaN magnetometer on a 6-axis sensor


@dataclass(slots=True)
class MarkMessage:
    seq: int
    t: float
    label: str


class NotJsonNumber:
    """What ``NaN``, ``Infinity`` or ``-Infinity`` in a message parse to. JSON has no such
    numbers and no check takes this for one, so the message is refused whole like any
    other with a bad value, naming its ``seq`` (the kit can drop it and go on)."""

    __slots__ = ("literal",)

    def __init__(self, literal: str):
        self.literal = literal

    def __repr__(self) -> str:
        return self.literal


_Value = float | None
_Row = tuple[_Value, _Value, _Value, _Value, _Value, _Value, _Value, _Value, _Value, _Value]


class _SamplesMessage(msgspec.Struct):
    """What a well-formed ``samples`` message decodes to on the fast path: every row 10
    numbers or nulls (no bool, no string), ``seq`` a whole number (other fields are left
    out, as the checks ignore them)."""

    type: Literal["samples"]  # required (a tag field would not be)
    seq: int
    sensor: str
    rows: list[_Row]


_decode_samples = msgspec.json.Decoder(_SamplesMessage).decode


def parse(text: str | bytes) -> dict[str, Any]:
    """A JSON object with a string ``type``; NaN and Infinity become :class:`NotJsonNumber`.

    A ``samples`` message whose rows are 1–1000 lists of 10 numbers or nulls comes back
    with ``rows`` already an (n, 10) float64 array (null → NaN): msgspec decodes it typed,
    in one pass, and refuses whatever the slow path would look at twice (a bool, a
    string, a row of another length, NaN, 1e400, bad syntax). Its float parsing gives the
    same doubles as orjson's and Python's (checked on 2,000,000 random doubles in five
    notations and 20,000 integers of 15 to 320 digits). Every other message, and every
    samples message it refuses, goes the slow path below, which names the fault.

    orjson parses the well-formed messages (about 10× faster than the standard library;
    its float parsing is correctly rounded, like Python's ``float``: checked on 400,000
    random doubles); what it refuses (NaN, 1e400, bad syntax) is parsed again by the
    standard library, which names the fault or lets the value checks refuse it."""
    try:
        fast = _decode_samples(text)
    except msgspec.MsgspecError:
        pass
    else:
        rows: list | np.ndarray = fast.rows
        if 1 <= len(fast.rows) <= MAX_ROWS:
            rows = _rows_array(fast.rows)
        return {"type": "samples", "seq": fast.seq, "sensor": fast.sensor, "rows": rows}
    try:
        message = orjson.loads(text)
    except orjson.JSONDecodeError:
        try:
            message = json.loads(text, parse_constant=NotJsonNumber)
        except (ValueError, RecursionError) as exc:
            raise Refused(f"malformed JSON: {exc}") from None
    if not isinstance(message, dict):
        raise Refused("a message must be a JSON object")
    kind = message.get("type")
    if not isinstance(kind, str):
        raise Refused("a message needs a string field 'type'")
    return message


def _rows_array(rows: list[tuple]) -> np.ndarray:
    """Typed rows (tuples of 10 floats or None) → (n, 10) float64, None → NaN."""
    try:  # a 9-axis sensor's rows: one flat pass
        return np.fromiter(chain.from_iterable(rows), np.float64,
                           ROW_WIDTH * len(rows)).reshape(len(rows), ROW_WIDTH)
    except TypeError:  # a null (6-axis magnetometer)
        return np.array(rows, dtype=np.float64)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    """A finite JSON number that a float64 holds (a whole number past ~1.8e308 is not)."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int too large for a float
        return False


def check_hello(message: dict[str, Any]) -> Hello:
    """The first message. A wrong ``protocol`` closes with 4400; other faults too, since
    nothing can follow a hello the server cannot use."""
    if message.get("type") != "hello":
        raise Refused(f"the first message must be a hello, got {message.get('type')!r}",
                      close_code=CLOSE_BAD_PROTOCOL)
    if message.get("protocol") != PROTOCOL_VERSION or isinstance(message.get("protocol"), bool):
        raise Refused(f"protocol {message.get('protocol')!r} is not supported "
                      f"(this server speaks {PROTOCOL_VERSION})", close_code=CLOSE_BAD_PROTOCOL)

    def bad(reason: str) -> Refused:
        return Refused(f"hello: {reason}", close_code=CLOSE_BAD_PROTOCOL)

    device = message.get("device")
    if not isinstance(device, str) or not 0 < len(device) <= 200:
        raise bad("device must be a name of 1 to 200 characters")
    problem = text_problem(device)
    if problem:
        raise bad(f"device must be valid text: {problem}")
    side = message.get("side")
    if side not in ("right", "left"):
        raise bad(f"side must be 'right' or 'left', got {side!r}")
    sensors = message.get("sensors")
    if (not isinstance(sensors, list) or not sensors
            or not all(isinstance(s, str) for s in sensors)):
        raise bad("sensors must be a non-empty list of sensor names")
    unknown = [s for s in sensors if s not in SENSOR_NAMES]
    if unknown:
        raise bad(f"unknown sensor {unknown[0]!r} (expected some of {', '.join(SENSOR_NAMES)})")
    if len(set(sensors)) != len(sensors):
        raise bad("a sensor is named twice")
    rate = message.get("rate_hz")
    if rate is not None and not (_is_number(rate) and 0 < rate <= 10000):
        raise bad(f"rate_hz must be a positive number of samples per second, got {rate!r}")
    nine_axis = message.get("nine_axis")
    if not isinstance(nine_axis, bool):
        raise bad(f"nine_axis must be true or false, got {nine_axis!r}")
    resume = message.get("resume")
    if resume is not None and (not isinstance(resume, str) or not 0 < len(resume) <= 40
                               or text_problem(resume)):
        raise bad("resume must be null or the stream id of an earlier connection")
    session = message.get("session")
    if session is not None and not (_is_int(session) and 0 < session < 2**31):
        raise bad(f"session must be null or the id of a session to continue, got {session!r}")
    if session is not None and resume is not None:
        raise bad("give resume (the same stream) or session (a new stream in that "
                  "session), not both")
    points = None
    if message.get("points") is not None:
        try:
            points = check_declaration(message["points"])
        except ValueError as exc:
            raise bad(str(exc)) from None
        if "upper_arm" not in sensors:
            raise bad("points need an upper_arm sensor (the γ elbow uses its tilt)")
    extensions = message.get("extensions", [])
    if (not isinstance(extensions, list) or len(extensions) > MAX_EXTENSIONS
            or not all(isinstance(e, str) and EXTENSION_PATTERN.fullmatch(e)
                       for e in extensions)):
        raise bad(f"extensions must be a list of at most {MAX_EXTENSIONS} names "
                  "'name/version' (like 'feedback/1')")
    delay = message.get("gyro_delay_s")
    if delay is not None:
        if not (_is_number(delay) and 0 <= delay <= GYRO_DELAY_MAX_S):
            raise bad(f"gyro_delay_s must be null or a number of seconds from 0 to "
                      f"{GYRO_DELAY_MAX_S} (how far the gyroscopes lag the "
                      f"accelerometers), got {delay!r}")
        delay = float(delay)
    return Hello(device, side, tuple(sensors), None if rate is None else float(rate),
                 nine_axis, resume, session, points=points, extensions=tuple(extensions),
                 gyro_delay_s=delay)


def check_seq(message: dict[str, Any]) -> int:
    seq = message.get("seq")
    if not _is_int(seq) or seq < 0:
        raise Refused(f"{message['type']}: seq must be a whole number ≥ 0, got {seq!r}")
    return seq


def check_samples(message: dict[str, Any], seq: int, hello: Hello,
                  last_t: dict[str, float], t_offset: float = 0.0) -> Samples:
    """A ``samples`` message: known sensor, 1–1000 rows of 10 finite numbers (``null``
    magnetometer exactly when 6-axis), within physical range, ``t`` non-decreasing within
    the message and after the sensor's last stored sample. ``t_offset`` [s] is added to
    ``t`` first (a stream continuing a session on a restarted clock; 0 otherwise)."""
    sensor = message.get("sensor")
    if sensor not in hello.sensors:
        raise Refused(f"sensor {sensor!r} was not named in hello "
                      f"({', '.join(hello.sensors)})", seq)
    rows = message.get("rows")
    if isinstance(rows, np.ndarray):  # parse's fast path: 1–1000 rows of 10, as float64
        data = rows
    else:
        if not isinstance(rows, list) or not 1 <= len(rows) <= MAX_ROWS:
            raise Refused(f"rows must be a list of 1 to {MAX_ROWS} rows", seq)
        data = _numbers(rows)
        if data is None:
            data = _numbers_or_refuse(rows, seq)
    if t_offset:
        data[:, 0] += t_offset
    if not plausible_rows(data, hello.nine_axis):
        _explain(data, sensor, seq, hello.nine_axis)  # raises, naming the first fault
    t = data[:, 0]
    previous = last_t.get(sensor)
    if previous is not None and t[0] < previous:
        raise Refused(backwards_message(sensor, t[0], previous)
                      + ": the clock went back; a kit whose clock restarted starts a new "
                      "stream in this session (hello with resume null and session = its id)",
                      seq)
    _check_time_bounds(t, sensor, previous, seq)
    return Samples(seq, sensor, data)


def _check_time_bounds(t: np.ndarray, sensor: str, previous: float | None, seq: int) -> None:
    """``docs/extensions/time-bounds.md``: ``|t| ≤ T_LIMIT_S``, and each ``t`` at most
    ``STEP_LIMIT_S`` after the sensor's previous one (rows already non-decreasing)."""
    if t[0] < -T_LIMIT_S or t[-1] > T_LIMIT_S:
        row = int(np.argmax(np.abs(t) > T_LIMIT_S))
        raise Refused(f"row {row}: " + time_beyond_message("t", t[row]), seq)
    if previous is not None and t[0] - previous > STEP_LIMIT_S:
        raise Refused("row 0: " + step_beyond_message(sensor, t[0], previous), seq)
    if t.size > 1 and t[-1] - t[0] > STEP_LIMIT_S:
        steps = np.diff(t)
        if (steps > STEP_LIMIT_S).any():
            row = int(np.argmax(steps > STEP_LIMIT_S)) + 1
            raise Refused(f"row {row}: " + step_beyond_message(sensor, t[row], t[row - 1]),
                          seq)


_NUMBER_TYPES = frozenset((float, int, type(None)))


def _numbers(rows: list) -> np.ndarray | None:
    """The rows as an (n, 10) float64 array (null → NaN) when every row is a list of 10
    numbers or nulls; None when anything is off (``_numbers_or_refuse`` names it). One
    C-level scan of the values' types (no bool, no string: NumPy would take "1.5" and
    true as numbers), then NumPy's conversion, whose shape shows a row of another length
    or a row that is no list."""
    try:
        kinds = set(map(type, chain.from_iterable(rows)))
    except TypeError:  # a row that is a number, null or true/false
        return None
    if not kinds <= _NUMBER_TYPES:  # a string, a bool, a list, NaN/Infinity, or a row
        return None  # that is a string or an object (their characters or keys)
    try:
        data = np.array(rows, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        return None
    return data if data.shape == (len(rows), ROW_WIDTH) else None


def _numbers_or_refuse(rows: list, seq: int) -> np.ndarray:
    """``_numbers`` checked step by step, raising the refusal that names the fault."""
    if set(map(type, rows)) != {list} or set(map(len, rows)) != {ROW_WIDTH}:
        raise Refused(f"every row must be a list of {ROW_WIDTH} values "
                      "[t, ax, ay, az, gx, gy, gz, mx, my, mz]", seq)
    kinds = set(map(type, chain.from_iterable(rows)))
    if not kinds <= _NUMBER_TYPES:
        odd = next(k for k in kinds if k not in (float, int, type(None)))
        if odd is NotJsonNumber:
            literal = next(v for v in chain.from_iterable(rows) if type(v) is NotJsonNumber)
            raise Refused(f"row values must be finite numbers: {literal!r} is not a number "
                          "JSON allows", seq)
        raise Refused(f"row values must be numbers (or null magnetometer), got a {odd.__name__}"
                      if odd is not bool else "row values must be numbers, got true/false", seq)
    try:
        return np.array(rows, dtype=np.float64)
    except OverflowError:
        raise Refused("a row value is too large for a float64", seq) from None


_COLUMNS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
#: Largest norm of acc, gyr, mag, in the order of a row.
_NORM_LIMITS = np.array([LIMITS[q][1] for q in ("acc", "gyr", "mag")])


def plausible_numpy(data: np.ndarray, nine_axis: bool) -> bool:
    """Every rule of a samples message's rows, in a few whole-array operations. The same
    float64 operations as the recording reader's range check, so a boundary value is
    judged alike. The reference of the compiled ``plausible_rows`` (and its fallback)."""
    if nine_axis:
        if not np.isfinite(data).all():
            return False
    elif not (np.isfinite(data[:, :7]).all() and np.isnan(data[:, 7:]).all()):
        return False
    with np.errstate(over="ignore"):  # a huge value squares to inf: beyond range all the same
        squares = data[:, 1:] * data[:, 1:]
        norms = np.sqrt(squares[:, 0::3] + squares[:, 1::3] + squares[:, 2::3])  # (n, 3)
    if (norms > _NORM_LIMITS).any():  # a 6-axis NaN norm compares False
        return False
    return not (data[1:, 0] < data[:-1, 0]).any()


def _plausible_loop(data: np.ndarray, nine_axis: bool, limits: np.ndarray) -> bool:
    """``plausible_numpy`` as one pass over the rows (compiled by numba: the hot path
    costs one call instead of a dozen array operations)."""
    for i in range(data.shape[0]):
        for j in range(7 if not nine_axis else 10):
            if not math.isfinite(data[i, j]):
                return False
        if not nine_axis:
            for j in range(7, 10):
                if not math.isnan(data[i, j]):
                    return False
        for k in range(3 if nine_axis else 2):
            x, y, z = data[i, 1 + 3 * k], data[i, 2 + 3 * k], data[i, 3 + 3 * k]
            if math.sqrt(x * x + y * y + z * z) > limits[k]:
                return False
        if i > 0 and data[i, 0] < data[i - 1, 0]:
            return False
    return True


def _compile_plausible():
    jit = compiler(nogil=True)
    if jit is None:  # pragma: no cover - numba is a dependency
        return plausible_numpy
    kernel = jit(_plausible_loop)

    def plausible_rows(data: np.ndarray, nine_axis: bool) -> bool:
        return bool(kernel(data, nine_axis, _NORM_LIMITS))

    return plausible_rows


#: The hot-path check of a message's rows (see ``plausible_numpy``).
plausible_rows = _compile_plausible()


def _explain(data: np.ndarray, sensor: str, seq: int, nine_axis: bool) -> None:
    """Raise the refusal that names the first fault of rows ``plausible_rows`` refused."""
    missing = np.isnan(data)  # only null can give NaN: NotJsonNumber was refused above
    if missing[:, :7].any():
        row, col = map(int, np.argwhere(missing[:, :7])[0])
        raise Refused(f"row {row}: column {_COLUMNS[col]} is null", seq)
    if nine_axis:
        if missing[:, 7:].any():
            raise Refused(f"sensor {sensor} is 9-axis: mx my mz must be numbers", seq)
    elif not missing[:, 7:].all():
        raise Refused(f"sensor {sensor} is 6-axis: mx my mz must be null", seq)
    finite = np.isfinite(data[:, :7]).all() and (not nine_axis
                                                 or np.isfinite(data[:, 7:]).all())
    if not finite:
        raise Refused("a row value is too large for a float64", seq)
    for quantity, columns in (("acc", slice(1, 4)), ("gyr", slice(4, 7)), ("mag", slice(7, 10))):
        if quantity == "mag" and not nine_axis:
            continue
        block = data[:, columns]
        with np.errstate(over="ignore"):  # a huge value squares to inf: beyond all the same
            over = beyond_range(quantity, block[:, 0], block[:, 1], block[:, 2])
        if over.any():
            row = int(np.argmax(over))
            symbol, limit, unit = LIMITS[quantity]
            with np.errstate(over="ignore"):
                value = float(np.sqrt(np.sum(block[row] ** 2)))
            raise Refused(f"row {row}: {symbol} = {value:.6g} {unit} is beyond the physical "
                          f"range ({symbol} ≤ {limit:g} {unit})", seq)
    t = data[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise Refused(f"row {i}: " + backwards_message(sensor, t[i], t[i - 1]), seq)
    raise AssertionError("_explain found nothing wrong with rows plausible_rows refused")


def check_points(message: dict[str, Any], seq: int, hello: Hello, last_t: dict[str, float],
                 t_offset: float = 0.0) -> Samples:
    """A ``points`` message (``docs/extensions/points.md``) as the rows of its pseudo-sensor
    ``point:<name>`` ([t, x, y, z] and six NaN), refused whole naming ``seq``."""
    try:
        name, data = _points.check_points(message, hello.points, last_t, t_offset)
    except ValueError as exc:
        raise Refused(str(exc), seq) from None
    return Samples(seq, name, data)


def check_mark(message: dict[str, Any], seq: int, t_offset: float = 0.0) -> MarkMessage:
    t = message.get("t")
    if not _is_number(t):
        raise Refused(f"mark: t must be a finite number of seconds, got {t!r}", seq)
    label = message.get("label")
    if isinstance(label, str) and len(label) > MARK_LABEL_MAX:
        raise Refused(f"mark: label is {len(label)} characters long, at most "
                      f"{MARK_LABEL_MAX}", seq)
    if not isinstance(label, str) or not LABEL_PATTERN.fullmatch(label):
        raise Refused(f"mark: label must be npose, tpose, exercise:<name> or end:<label>, "
                      f"got {label!r}", seq)
    t = float(t) + t_offset if t_offset else float(t)
    if not abs(t) <= T_LIMIT_S:
        raise Refused("mark: " + time_beyond_message("t", t), seq)
    return MarkMessage(seq, t, label)


def check_status(message: dict[str, Any], hello: Hello) -> dict[str, Any]:
    """A ``status`` message: what the dashboard shows of a sensor (not stored)."""
    sensor = message.get("sensor")
    if sensor not in hello.sensors:
        raise Refused(f"status: sensor {sensor!r} was not named in hello")
    status: dict[str, Any] = {"sensor": sensor}
    battery = message.get("battery")
    if battery is not None:
        if not (_is_number(battery) and 0 <= battery <= 1):
            raise Refused(f"status: battery must be a fraction 0…1, got {battery!r}")
        status["battery"] = float(battery)
    rssi = message.get("rssi_dbm")
    if rssi is not None:
        if not (_is_number(rssi) and -150 <= rssi <= 20):
            raise Refused(f"status: rssi_dbm must be a number of dBm, got {rssi!r}")
        status["rssi_dbm"] = float(rssi)
    return status


def dumps(message: dict[str, Any]) -> str:
    """Compact JSON text (floats in their shortest round-trip form). An integer beyond 64
    bits (a kit's ``seq`` of 400 digits, named back in its ``error``), which ``orjson``
    refuses, is written by the standard library: JSON's integers have no limit."""
    try:
        return orjson.dumps(message).decode()
    except TypeError:
        return json.dumps(message, separators=(",", ":"), ensure_ascii=False,
                          allow_nan=False)
