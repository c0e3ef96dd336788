"""Reading the text of vendor CSV exports: lines, separators and columns of numbers, with
errors that name the file and the line."""

from __future__ import annotations

import math

import numpy as np

from .base import ImportFailure, SourceFile

#: Fewest bytes a sensor's data line averages: a time and three numbers with their
#: separators and line end (``0,1,2,3`` + newline). A Python line costs ~60 bytes beyond
#: its text, so a file of shorter lines would cost the reader over 8x its size.
MIN_LINE_BYTES = 8
#: Most cells a line among the first ``HEAD_LINES`` (the header) may hold: an export has
#: a few dozen columns.
MAX_HEADER_CELLS = 1000
HEAD_LINES = 64
#: Rows checked at a time where Arrow refused the data (the extra memory of the check).
CHECK_ROWS = 1 << 16


def text_lines(source: SourceFile) -> list[str]:
    """The file's lines without line endings (UTF-8, a BOM dropped; Latin-1 if not UTF-8,
    as spreadsheet programs on Windows save).

    Refuses, before splitting, a file whose lines average under ``MIN_LINE_BYTES`` (no
    sensor data; its lines would cost the reader tens of times the file's size) and a
    header line of more than ``MAX_HEADER_CELLS`` cells."""
    data = source.data
    lines = data.count(b"\n") or data.count(b"\r")
    if lines > 1000 and len(data) < MIN_LINE_BYTES * lines:
        raise ImportFailure(source.name, f"holds {lines} lines of {len(data) / lines:.1f} "
                            f"bytes on average: a sensor's data line holds at least a time "
                            f"and three numbers ({MIN_LINE_BYTES} bytes)")
    head = data[:1 << 20].splitlines()[:HEAD_LINES]
    for number, line in enumerate(head, 1):
        cells = 1 + max(line.count(sep) for sep in (b",", b";", b"\t"))
        if cells > MAX_HEADER_CELLS:
            raise ImportFailure(source.name, f"{cells} cells: an export's header holds at "
                                f"most {MAX_HEADER_CELLS}", number)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return text.splitlines()


def head_text(source: SourceFile, size: int = 4096) -> str:
    """The start of the file as text, for telling formats apart."""
    return source.data[:size].decode("utf-8-sig", errors="replace")


def split_line(line: str, delimiter: str) -> list[str]:
    """A line's cells, spaces and surrounding double quotes removed."""
    return [cell.strip().strip('"').strip() for cell in line.split(delimiter)]


def numeric_columns(source: SourceFile, lines: list[str], first: int, delimiter: str,
                    width: int, wanted: dict[str, int], names: dict[str, str] | None = None,
                    optional: frozenset[str] = frozenset(), integers: frozenset[str] = frozenset()
                    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Numbers of the data lines ``lines[first:]``: each of ``wanted`` (key → column
    index) as float64, and each row's line number (1-based).

    Refuses a line with fewer cells than the header's ``width`` (a truncated file), an
    empty cell in a column not in ``optional`` (which then reads NaN), text that is no
    number and a non-finite number, naming the line and the column (``names``). Keys in
    ``integers`` are read as int64 when every cell is a whole number (exact beyond 2⁵³,
    for ns time stamps)."""
    rows = lines[first:]
    while rows and not rows[-1].strip(" \t,;\"'"):
        rows.pop()  # blank lines (or bare separators) at the end
    if not rows:
        raise ImportFailure(source.name, "no data lines after the header", first)
    fast = _arrow_columns(rows, delimiter, width, wanted, optional, integers)
    if fast is not None:
        return fast, np.arange(first + 1, first + 1 + len(rows))
    # Arrow refused something: find the line and say what, cell by cell, a block of
    # CHECK_ROWS rows at a time (splitting every row at once cost ~40x the file's size)
    parts: dict[str, list[np.ndarray]] = {key: [] for key in wanted}
    for start in range(0, len(rows), CHECK_ROWS):
        block = _checked_block(source, rows, start, first, delimiter, width, wanted, names,
                               optional, integers)
        for key, values in block.items():
            parts[key].append(values)
    # int64 only where every block was whole numbers (else float64, as if read whole)
    out = {key: np.concatenate(values) for key, values in parts.items()}
    return out, np.arange(first + 1, first + 1 + len(rows))


def _checked_block(source: SourceFile, rows: list[str], start: int, first: int,
                   delimiter: str, width: int, wanted: dict[str, int],
                   names: dict[str, str] | None, optional: frozenset[str],
                   integers: frozenset[str]) -> dict[str, np.ndarray]:
    """The wanted columns of ``rows[start:start + CHECK_ROWS]``, or the refusal naming its
    first bad line (``first``: the index of ``rows[0]`` among the file's lines)."""
    block = rows[start:start + CHECK_ROWS]
    fast = _arrow_columns(block, delimiter, width, wanted, optional, integers)
    if fast is not None:  # the fault is in another block
        return fast
    split = [row.split(delimiter) for row in block]
    first += start
    counts = np.fromiter(map(len, split), dtype=np.int64, count=len(split))
    short = np.flatnonzero(counts < width)
    if short.size:
        i = int(short[0])
        what = ("the last line is cut short: the file is truncated"
                if start + i == len(rows) - 1 else "the line is cut short or damaged")
        raise ImportFailure(source.name, f"{counts[i]} cells where the header has {width}: "
                            f"{what}", first + i + 1)
    out: dict[str, np.ndarray] = {}
    for key, index in wanted.items():
        cells = [cells[index].strip().strip('"') for cells in split]
        label = (names or {}).get(key, key)
        if key in integers:
            try:
                out[key] = np.array(cells, dtype=np.int64)
                continue
            except (ValueError, OverflowError):
                pass  # not all whole numbers: read as float64 below
        try:
            if key in optional:
                values = np.array([c if c else "nan" for c in cells], dtype=np.float64)
            else:
                values = np.array(cells, dtype=np.float64)
        except ValueError:
            _refuse_cell(source, cells, first, label, key in optional)
        if key not in optional:
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                i = int(bad[0])
                raise ImportFailure(source.name, f"{label} is not a finite number "
                                    f"({cells[i]!r})", first + i + 1)
        out[key] = values
    return out


def _arrow_columns(rows: list[str], delimiter: str, width: int, wanted: dict[str, int],
                   optional: frozenset[str], integers: frozenset[str]
                   ) -> dict[str, np.ndarray] | None:
    """The columns parsed by Arrow's CSV reader (C++, ~20x the Python split), or None when
    anything is off (a short or long line, an empty or non-numeric cell, a non-finite
    number): the caller then finds the line and the problem itself."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    cells = rows[0].count(delimiter) + 1
    if cells < width:
        return None
    names = [f"c{i}" for i in range(cells)]
    types = {names[i]: (pa.int64() if key in integers else pa.float64())
             for key, i in wanted.items()}
    try:
        table = pacsv.read_csv(
            pa.py_buffer("\n".join(rows).encode("utf-8")),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=True),
            parse_options=pacsv.ParseOptions(delimiter=delimiter),
            convert_options=pacsv.ConvertOptions(
                column_types=types, include_columns=[names[i] for i in wanted.values()],
                strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowInvalid, pa.ArrowTypeError, UnicodeEncodeError):
        return None
    if table.num_rows != len(rows):
        return None
    out = {}
    for key, index in wanted.items():
        column = table.column(names[index])
        if column.null_count and key not in optional:
            return None
        values = column.to_numpy(zero_copy_only=False)
        if key in integers:
            out[key] = values.astype(np.int64, copy=False)
            continue
        values = values.astype(np.float64, copy=False)
        if key not in optional and not np.isfinite(values).all():
            return None
        out[key] = values
    return out


def _refuse_cell(source: SourceFile, cells: list[str], first: int, label: str,
                 optional: bool) -> None:
    for i, cell in enumerate(cells):  # the error path only: find the first bad cell
        if optional and not cell:
            continue
        try:
            value = float(cell)
        except ValueError:
            problem = "is empty" if not cell else f"is not a number ({cell!r})"
            raise ImportFailure(source.name, f"{label} {problem}", first + i + 1) from None
        if not math.isfinite(value):
            raise ImportFailure(source.name, f"{label} is not a finite number ({cell!r})",
                                first + i + 1)
    raise ImportFailure(source.name, f"{label} holds a value that is not a number", first + 1)
