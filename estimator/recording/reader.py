"""Reading recording files (``docs/spec/recording.md``, version 1): strict, fast, all or nothing.

A file that breaks a rule raises :class:`InvalidRecording` naming the first offending
line (1-based, header lines included) and the rule; nothing is returned. The rules are
in ``header.py`` (header and column line), ``rows.py`` (data rows) and ``rules.py``
(numbers, ranges). Beyond the spec, this reader decides:
- a UTF-8 byte order mark at the very start is skipped (spreadsheets write one);
  line numbers are unaffected;
- lines end in LF or CRLF, mixed is fine; a carriage return anywhere else is refused;
- blank lines at the end of the file are fine, anywhere else refused (also before the
  column line); lines of only spaces are not blank and are refused;
- numbers are plain decimals (``rules.NUMBER``), optionally signed, with an optional
  exponent (``1e-300``); ``inf``, ``nan``, hex, spaces, underscores, quotes are refused;
- an unsupported ``armtrack-recording`` version is reported before any other error;
- a file must have at least one data row; each sensor present has at least one.

Fast path: the data rows go to ``pyarrow.csv`` (explicit types, quoting off, empty as
null, blank lines kept as rows) and are validated vectorised in numpy; row i is line
``column_line + 1 + i``. Arrow's float parser (fast_float) is correctly rounded, so the
values equal Python's ``float()`` of the text (tests check this on random bit patterns,
long decimal strings and exact halfway cases). Arrow also accepts things these rules
refuse (spaces around numbers, ``inf``, ``nan``, bare CR as a line end, a BOM at the
start of its input): files with spaces, tabs, bare CR or a BOM before the first data row
skip the fast path, and non-finite values are refused by the vectorised checks. When
a check fails, ``rows.RowChecker`` words the error of the first flagged line. When Arrow
refuses the text, it is parsed again in pieces of about 1 MiB, and only the pieces Arrow
refuses go through the line-by-line pass, which finds the first bad line and its rule.
"""

from __future__ import annotations

import os

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from ..body import SENSOR_NAMES
from ..errors import InvalidRecording
from .header import Header, read_header
from .model import POINTS_VERSION, Recording
from .points import (
    POINTS_COLUMN_LINE,
    POINTS_HEADER_KEYS,
    PointsFrame,
    PointStream,
    frame_from_header,
    parse_points,
)
from .rows import (
    RowChecker,
    Rows,
    checker_after,
    concat,
    explain,
    first_bad_row,
    parse_rows_slow,
    streams,
)
from .rules import COLUMNS, NUMERIC, UTF8_BOM

_READ = pacsv.ReadOptions(column_names=list(COLUMNS), block_size=4 << 20)
_PARSE = pacsv.ParseOptions(
    delimiter=",",
    quote_char=False,
    double_quote=False,
    escape_char=False,
    newlines_in_values=False,
    ignore_empty_lines=False,
)
_CONVERT = pacsv.ConvertOptions(
    column_types={
        "sensor": pa.dictionary(pa.int32(), pa.string()),
        **{name: pa.float64() for name in NUMERIC},
    },
    null_values=[""],
    true_values=[],
    false_values=[],
    strings_can_be_null=False,
    quoted_strings_can_be_null=False,
    check_utf8=True,
)
_NAMES = pa.array(SENSOR_NAMES, pa.string())
_PIECE = 1 << 20  # bytes per piece when locating an error Arrow refused


def read_recording(source: str | os.PathLike[str] | bytes) -> Recording:
    """Read a recording from a file path, or from the file's bytes."""
    if isinstance(source, bytes | bytearray | memoryview):
        return parse_recording(bytes(source))
    with open(source, "rb") as f:
        return parse_recording(f.read())


def parse_recording(data: bytes) -> Recording:
    """Parse the bytes of a recording file; raises InvalidRecording if any rule is broken."""
    return _parse(bytes(data), fast=True)


def _parse(data: bytes, fast: bool) -> Recording:
    start = len(UTF8_BOM) if data.startswith(UTF8_BOM) else 0
    header = read_header(data, start)
    begin, end = header.body_start, _content_end(data, header.body_start)
    first_line = header.column_line + 1
    points, frame = {}, None
    if header.version >= POINTS_VERSION:
        end, points, frame = _points(data, header, begin, end)
    else:
        at = _points_column(data, begin, end)
        if at >= 0:
            line = header.column_line + 1 + data.count(b"\n", begin, at + 1)
            raise InvalidRecording(f"a points section ({POINTS_COLUMN_LINE}) needs "
                                   f"'armtrack-recording: {POINTS_VERSION}'", line)
    if begin >= end:
        raise InvalidRecording("no data rows after the column line", first_line)
    if fast:
        rows = _parse_fast(data, begin, end)
        if rows is None:
            rows = _parse_pieces(data, begin, end, first_line)
        _check(rows, data, begin, first_line)
    else:
        rows = parse_rows_slow(data[begin:end].split(b"\n"), first_line)
    return _recording(header, rows, points, frame)


def _points(data: bytes, header: Header, begin: int, end: int
            ) -> tuple[int, dict[str, PointStream], PointsFrame | None]:
    """A version-2 file's points section (``docs/extensions/points.md``): the end of the
    IMU rows, the points and their frame. The section starts at the first line that is
    exactly ``t,point,x,y,z``; the extension's header keys leave the metadata."""
    values = {key: (header.metadata.pop(key), header.key_lines[key])
              for key in POINTS_HEADER_KEYS if key in header.metadata}
    at = _points_column(data, begin, end)
    if at < 0:
        frame = frame_from_header(values, header.column_line) if values else None
        return end, {}, frame
    column_line = header.column_line + 1 + data.count(b"\n", begin, at + 1)
    frame = frame_from_header(values, column_line)
    rows_start = data.find(b"\n", at + 1, end)
    if rows_start < 0:
        raise InvalidRecording("no point rows after the points column line", column_line)
    points = parse_points(data[rows_start + 1:end].split(b"\n"), column_line + 1)
    imu_end = at - 1 if at > begin and data[at - 1] == 0x0D else at
    return imu_end, points, frame


def _check(rows: Rows, data: bytes, begin: int, first_line: int) -> None:
    """Raise the first rule broken by the rows starting at byte ``begin``, if any."""
    bad = first_bad_row(rows)
    if bad is not None:
        raw = data[begin:].split(b"\n", bad + 1)[bad]
        raise explain(rows, bad, raw, first_line + bad)


def _parse_pieces(data: bytes, begin: int, end: int, first_line: int) -> Rows:
    """Rows of a body that Arrow refused whole: line-aligned pieces of about ``_PIECE``
    bytes go to Arrow one by one; a piece it refuses goes through the line-by-line pass,
    from the state the rows before it leave (after checking those rows), and that pass
    raises at its first bad line. So a broken file costs about one more parse, not a
    line-by-line pass over all of it."""
    parts: list[Rows] = []
    pos, line = begin, first_line
    while pos < end:
        stop = data.find(b"\n", min(pos + _PIECE, end), end)
        stop = end if stop < 0 else stop
        rows = _parse_fast(data, pos, min(stop + 1, end))
        if rows is None:
            checker = RowChecker()
            if parts:
                done = concat(parts)
                _check(done, data, begin, first_line)
                checker = checker_after(done, len(done.codes), first_line)
            rows = parse_rows_slow(data[pos:stop].split(b"\n"), line, checker)
        parts.append(rows)
        pos, line = stop + 1, line + len(rows.codes)
    return concat(parts)


def _content_end(data: bytes, begin: int) -> int:
    """End of the data rows: trailing blank lines (LF or CRLF) dropped."""
    end = len(data)
    while end > begin and data[end - 1] == 0x0A:
        end -= 2 if end - 1 > begin and data[end - 2] == 0x0D else 1
    return end


def _parse_fast(data: bytes, begin: int, end: int) -> Rows | None:
    """Parse data rows with pyarrow; None when the text needs the line-by-line pass."""
    if data.find(b" ", begin, end) >= 0 or data.find(b"\t", begin, end) >= 0:
        return None
    if data.startswith(UTF8_BOM, begin):  # Arrow would skip it silently
        return None
    if data.find(b"\r", begin, end) >= 0 and (
        data.count(b"\r", begin, end) != data.count(b"\r\n", begin, end)
    ):
        return None
    body = pa.py_buffer(data).slice(begin, end - begin)
    try:
        table = pacsv.read_csv(
            pa.BufferReader(body),
            read_options=_READ,
            parse_options=_PARSE,
            convert_options=_CONVERT,
        )
    except pa.ArrowException:
        return None
    n = table.num_rows
    values = np.empty((len(NUMERIC), n))
    for j, name in enumerate(NUMERIC):
        values[j] = table.column(name).to_numpy()
    mag_null = np.zeros((3, n), dtype=bool)
    for j, name in enumerate(("mx", "my", "mz")):
        column = table.column(name)
        if column.null_count:
            mag_null[j] = column.is_null().to_numpy()
    return Rows(_codes(table.column("sensor")), values, mag_null)


def _codes(column: pa.ChunkedArray) -> np.ndarray:
    """Index into SENSOR_NAMES per row, -1 for unknown names."""
    parts = []
    for chunk in column.chunks:
        lookup = pc.index_in(chunk.dictionary, value_set=_NAMES).fill_null(-1)
        lookup = lookup.to_numpy().astype(np.int8)
        parts.append(lookup[chunk.indices.to_numpy()])
    return np.concatenate(parts) if parts else np.empty(0, dtype=np.int8)


def _points_column(data: bytes, begin: int, end: int) -> int:
    """Offset of the newline before the line ``t,point,x,y,z`` in the body, or -1."""
    marker = b"\n" + POINTS_COLUMN_LINE.encode()
    at = data.find(marker, begin - 1, end)
    while at >= 0 and not data.startswith((b"\n", b"\r\n"), at + len(marker)) \
            and at + len(marker) != end:
        at = data.find(marker, at + 1, end)
    return at


def _recording(header: Header, rows: Rows, points: dict[str, PointStream],
               frame: PointsFrame | None) -> Recording:
    return Recording(
        side=header.side,  # type: ignore[arg-type]  # checked by read_header
        sensors=streams(rows),
        height_m=header.height_m,
        lengths=header.lengths,
        calibration=header.calibration,
        marks=header.marks,
        rate_hz=header.rate_hz,
        metadata=header.metadata,
        points=points,
        points_frame=frame,
    )
