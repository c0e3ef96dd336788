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
