"""The small rules both directions share: columns, the number grammar, physical ranges,
and how one line of bytes becomes text.

Numbers are plain decimals: ``[+-]? digits [. digits] [(e|E) [+-] digits]`` with ASCII
digits (``1``, ``-0.5``, ``.5``, ``5.``, ``1e-300``); no spaces, underscores, quotes,
``inf`` or ``nan``. Their value is the float64 Python's ``float()`` gives for the text
(correctly rounded).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..errors import InvalidRecording

#: The column line, exactly.
COLUMNS: tuple[str, ...] = ("t", "sensor", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
COLUMN_LINE = ",".join(COLUMNS)
#: The numeric columns in the order of a row's 10 values.
NUMERIC: tuple[str, ...] = tuple(c for c in COLUMNS if c != "sensor")

NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")

#: Physical range of each 3-vector: (symbol, largest norm, unit). Beyond it, refused.
LIMITS: dict[str, tuple[str, float, str]] = {
    "acc": ("|a|", 160.0, "m/s²"),
    "gyr": ("|g|", 35.0, "rad/s"),
    "mag": ("|m|", 5000.0, "µT"),
}

UTF8_BOM = b"\xef\xbb\xbf"

#: Time bounds (``docs/extensions/time-bounds.md``), the same for recording files and
#: streams: a sample's, mark's or pose's time ``t`` [s] is within ±``T_LIMIT_S`` (any
#: uptime or Unix-epoch clock), and a sensor's sample comes at most ``STEP_LIMIT_S`` [s]
#: after that sensor's previous one (a day: far beyond a session's pause, far below what
#: breaks durations, rates and reports).
T_LIMIT_S = 1e10
STEP_LIMIT_S = 86_400.0


def time_beyond_message(what: str, t: float) -> str:
    return (f"{what} = {float(t)!r} s is beyond the time bounds (|t| ≤ {T_LIMIT_S:g} s, "
            "docs/extensions/time-bounds.md)")


def step_beyond_message(sensor: str, t: float, previous: float) -> str:
    return (f"t = {float(t)!r} s of sensor {sensor} comes {float(t) - float(previous):.6g} s "
            f"after its previous sample ({float(previous)!r} s): at most {STEP_LIMIT_S:g} s "
            "after (docs/extensions/time-bounds.md; a kit that stopped for longer starts a "
            "new session)")


def parse_number(text: str, what: str, line: int | None) -> float:
    """The finite float64 a plain decimal ``text`` stands for; refuses anything else."""
    if not NUMBER.fullmatch(text):
        try:
            value = float(text)
        except ValueError:
            value = 0.0
        if not math.isfinite(value):
            raise InvalidRecording(f"{what} is not finite ({text!r})", line)
        raise InvalidRecording(f"{what} is not a plain decimal number ({text!r})", line)
    value = float(text)
    if not math.isfinite(value):
        raise InvalidRecording(f"{what} is not finite ({text!r})", line)
    return value


def norm_sq(x, y, z):
    """Squared norm of a 3-vector, the same float64 operations for scalars and arrays
    (so the reader's vectorised and line-by-line checks agree to the last bit)."""
    return x * x + y * y + z * z


def beyond_range(quantity: str, x, y, z):
    """True where the norm of (x, y, z) exceeds the physical range of ``quantity``."""
    return np.sqrt(norm_sq(x, y, z)) > LIMITS[quantity][1]


def range_message(quantity: str, sensor: str, vector) -> str:
    symbol, limit, unit = LIMITS[quantity]
    value = math.hypot(*(float(v) for v in vector))
    return (
        f"{symbol} = {value:.6g} {unit} of sensor {sensor} is beyond the physical range "
        f"({symbol} ≤ {limit:g} {unit})"
    )


def backwards_message(sensor: str, t: float, previous: float) -> str:
    return f"t goes backwards for sensor {sensor} ({float(t)!r} after {float(previous)!r})"


def decode_line(raw: bytes, line: int) -> str:
    """One line's text without its line ending (LF or CRLF); refuses a carriage return
    elsewhere and bytes that are not UTF-8."""
    if raw.endswith(b"\r"):
        raw = raw[:-1]
    if b"\r" in raw:
        raise InvalidRecording("stray carriage return (lines end with LF or CRLF)", line)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        message = f"not valid UTF-8 (byte {exc.start + 1} of the line)"
        raise InvalidRecording(message, line) from None
