"""Header lines (``# key: value``) and the column line: reading and writing.

Reading checks, in file order (one exception: an unsupported format version is reported
before anything else, since other versions have other rules):
- every line before the column line is ``#``, optional spaces, a key (letters, digits,
  ``_ . -``), optional spaces, ``:``, the value (surrounding whitespace dropped);
- no key appears twice;
- the first line not starting with ``#`` is exactly ``t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz``;
- ``armtrack-recording`` is ``1``; ``side`` is ``right`` or ``left``;
- ``height_m`` is a plausible height (0.5–2.6 m); ``lengths_m`` gives all four segments
  once each (``clavicle=0.23 upper_arm=0.33 forearm=0.26 hand=0.19``, in (0, 1.5) m);
  at least one of the two is present (with both, the lengths win);
- ``calibration`` is ``;``-separated ``NAME START END`` with NAME ``npose``/``tpose`` and
  START < END; ``marks`` is ``;``-separated ``T LABEL``; no empty entries;
- ``rate_hz`` is positive; every number is a finite plain decimal (``rules.NUMBER``);
- ``gyro_delay_s`` (extension ``docs/extensions/gyro-delay.md``) is 0 to 0.05 s; it stays
  in the metadata, as written.
Other keys are kept, in order, as metadata.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..body import HEIGHT_FRACTIONS, SIDES, SegmentLengths
from ..errors import InvalidArgument, InvalidRecording
from .model import (
    GYRO_DELAY_KEY,
    HEADER_KEYS,
    KEY_PATTERN,
    SUPPORTED_VERSIONS,
    Mark,
    Pose,
    Recording,
    check_metadata,
)
from .rules import COLUMN_LINE, decode_line, parse_number

_HEADER_LINE = re.compile(r"#[ \t]*([^:]*?)[ \t]*:(.*)", re.DOTALL)
_VERSION_LINE = re.compile(rb"#[ \t]*armtrack-recording[ \t]*:(.*)", re.DOTALL)


@dataclass
class Header:
    """What the header lines say; ``body_start`` is the byte offset of the first data row
    and ``column_line`` the column line's number (1-based)."""

    side: str = ""
    height_m: float | None = None
    lengths: SegmentLengths | None = None
    calibration: tuple[Pose, ...] = ()
    marks: tuple[Mark, ...] = ()
    rate_hz: float | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    body_start: int = 0
    column_line: int = 0
    version: int = 1
    key_lines: dict[str, int] = field(default_factory=dict)


def read_header(data: bytes, start: int) -> Header:
    """Read the header lines and the column line of ``data`` from byte ``start``."""
    if start >= len(data):
        raise InvalidRecording("empty file", 1)
    raw_lines: list[bytes] = []
    pos = start
    while pos < len(data) and data.startswith(b"#", pos):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        raw_lines.append(data[pos:end])
        pos = end + 1
    _check_version(raw_lines)

    header = Header()
    seen: dict[str, int] = {}
    for line, raw in enumerate(raw_lines, start=1):
        key, value = _split(decode_line(raw, line), line)
        if key in seen:
            message = f"duplicate header key {key!r} (first on line {seen[key]})"
            raise InvalidRecording(message, line)
        seen[key] = line
        _apply(header, key, value, line)
    header.key_lines = seen

    column_line = len(raw_lines) + 1
    if pos >= len(data):
        raise InvalidRecording(f"missing the column line {COLUMN_LINE!r}", column_line)
    end = data.find(b"\n", pos)
    end = len(data) if end < 0 else end
    text = decode_line(data[pos:end], column_line)
    if text != COLUMN_LINE:
        if not text:
            raise InvalidRecording("blank line before the column line", column_line)
        message = f"expected the column line {COLUMN_LINE!r}, got {text!r}"
        raise InvalidRecording(message, column_line)
    for key in ("armtrack-recording", "side"):
        if key not in seen:
            raise InvalidRecording(f"missing required header {key!r}", column_line)
    if "height_m" not in seen and "lengths_m" not in seen:
        message = "missing header 'height_m' or 'lengths_m' (one is required)"
        raise InvalidRecording(message, column_line)
    header.body_start = min(end + 1, len(data))
    header.column_line = column_line
    return header


def format_header(recording: Recording) -> str:
    """The header lines and the column line, in the spec's order, each ending in LF."""
    lines = [f"armtrack-recording: {recording.version}", f"side: {recording.side}"]
    if recording.height_m is not None:
        lines.append(f"height_m: {_number(recording.height_m)}")
    if recording.lengths is not None:
        lengths = recording.lengths.as_dict()
        lines.append("lengths_m: " + " ".join(f"{k}={_number(v)}" for k, v in lengths.items()))
    if recording.calibration:
        poses = (f"{p.name} {_number(p.start)} {_number(p.end)}" for p in recording.calibration)
        lines.append("calibration: " + "; ".join(poses))
    if recording.marks:
        lines.append("marks: " + "; ".join(f"{_number(m.t)} {m.label}" for m in recording.marks))
    if recording.rate_hz is not None:
        lines.append(f"rate_hz: {_number(recording.rate_hz)}")
    if recording.points_frame is not None:
        lines += recording.points_frame.header_lines()
    lines += [f"{k}: {v}" if v else f"{k}:" for k, v in recording.metadata.items()]
    return "".join(f"# {line}\n" for line in lines) + COLUMN_LINE + "\n"


def _number(value: float) -> str:
    """Shortest text that reads back as the same float64."""
    return repr(float(value))


def _check_version(raw_lines: list[bytes]) -> None:
    for line, raw in enumerate(raw_lines, start=1):
        match = _VERSION_LINE.fullmatch(raw.rstrip(b"\r"))
        if match:
            value = match.group(1).strip().decode("utf-8", "replace")
            supported = ", ".join(map(str, SUPPORTED_VERSIONS))
            if not value.isascii() or not value.isdigit():
                raise InvalidRecording(
                    f"armtrack-recording must be a format version (supported: {supported}), "
                    f"got {value!r}",
                    line,
                )
            if int(value) not in SUPPORTED_VERSIONS:
                raise InvalidRecording(
                    f"unsupported format version {value} (supported: {supported})", line
                )


def _split(text: str, line: int) -> tuple[str, str]:
    match = _HEADER_LINE.fullmatch(text)
    if not match:
        raise InvalidRecording(f"header line must be '# key: value', got {text!r}", line)
    key, value = match.group(1), match.group(2).strip()
    if not KEY_PATTERN.fullmatch(key):
        raise InvalidRecording(
            f"header key must be letters, digits, '_', '.', '-', got {key!r}", line
        )
    return key, value


def _apply(header: Header, key: str, value: str, line: int) -> None:
    """Check one header value and store it in ``header``."""
    if key not in HEADER_KEYS:
        if key == GYRO_DELAY_KEY:  # an extension's header, kept as metadata once checked
            try:
                check_metadata(key, value)
            except InvalidArgument as exc:
                raise InvalidRecording(str(exc), line) from None
        header.metadata[key] = value
        return
    try:
        if key == "armtrack-recording":
            header.version = int(value)  # checked by _check_version
        elif key == "side":
            if value not in SIDES:
                raise InvalidRecording(f"side must be right or left, got {value!r}", line)
            header.side = value
        elif key == "height_m":
            header.height_m = parse_number(value, "height_m", line)
            SegmentLengths.from_height(header.height_m)
        elif key == "lengths_m":
            header.lengths = _lengths(value, line)
        elif key == "calibration":
            header.calibration = tuple(
                _pose(item, line) for item in _items(value, "calibration", line)
            )
        elif key == "marks":
            header.marks = tuple(_mark(item, line) for item in _items(value, "marks", line))
        elif key == "rate_hz":
            header.rate_hz = parse_number(value, "rate_hz", line)
            if header.rate_hz <= 0:
                raise InvalidRecording(f"rate_hz must be positive, got {value!r}", line)
    except InvalidArgument as exc:
        raise InvalidRecording(f"{key}: {exc}", line) from None


def parse_calibration(value: str, line: int | None = None) -> tuple[Pose, ...]:
    """A ``calibration`` value (``npose 0.5 3.0; tpose 5.5 8.0``) as poses; refuses what the
    header line would refuse."""
    return tuple(_pose(item, line) for item in _items(value, "calibration", line))


def _items(value: str, key: str, line: int) -> list[str]:
    items = [item.strip() for item in value.split(";")]
    if not all(items):
        raise InvalidRecording(f"{key} has an empty entry (entries are separated by ';')", line)
    return items


def _lengths(value: str, line: int) -> SegmentLengths:
    found: dict[str, float] = {}
    for token in value.split():
        name, eq, number = token.partition("=")
        if not eq:
            raise InvalidRecording(f"lengths_m entry must be segment=metres, got {token!r}", line)
        if name not in HEIGHT_FRACTIONS:
            expected = ", ".join(HEIGHT_FRACTIONS)
            raise InvalidRecording(
                f"lengths_m: unknown segment {name!r} (expected {expected})", line
            )
        if name in found:
            raise InvalidRecording(f"lengths_m gives {name} twice", line)
        found[name] = parse_number(number, f"lengths_m {name}", line)
    missing = [name for name in HEIGHT_FRACTIONS if name not in found]
    if missing:
        raise InvalidRecording(f"lengths_m misses {', '.join(missing)} (all four are needed)", line)
    return SegmentLengths(**found)


def _pose(item: str, line: int) -> Pose:
    parts = item.split()
    if len(parts) != 3:
        raise InvalidRecording(f"calibration entry must be 'NAME START END', got {item!r}", line)
    name, start, end = parts
    if name not in ("npose", "tpose"):
        raise InvalidRecording(f"calibration pose must be npose or tpose, got {name!r}", line)
    return Pose(
        name,
        parse_number(start, f"calibration {name} start", line),
        parse_number(end, f"calibration {name} end", line),
    )


def _mark(item: str, line: int) -> Mark:
    parts = item.split()
    if len(parts) != 2:
        raise InvalidRecording(f"marks entry must be 'T LABEL', got {item!r}", line)
    return Mark(parse_number(parts[0], "mark time", line), parts[1])
