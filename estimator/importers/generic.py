"""Any CSV with a column map given by the user (``--columns``):

``t=COL[:UNIT] ax=COL[:UNIT] ay=… az=… gx=… gy=… gz=… [mx=… my=… mz=…] [sensor=COL]``

COL is a column name of the header line (quote it when it holds spaces:
``"ax='Acc X':g"``); a ``-`` before COL flips its sign (to turn a left-handed or
gravity-down device into the recording's convention); UNIT one of s, ms, us, ns (t),
m/s^2, g (a), rad/s, deg/s (g), uT, T, nT, G (m); defaults s, m/s^2, rad/s, uT.
``sensor=COL`` splits the rows by that column's value (one file, several sensors: pick one
with ``SENSOR=FILE:VALUE``). The separator (``,`` ``;`` tab) is taken from the header
line; lines starting with ``#`` before it are skipped. Times above 10⁸ s are taken as
seconds since 1970 UTC (``unix`` clock), smaller ones as the file's own clock.
"""

from __future__ import annotations

import shlex

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .text import numeric_columns, split_line, text_lines
from .units import seconds, unit_factor

NAME = "generic"
TITLE = "CSV with a column map (--columns)"
KEYS = {"t": "time", "ax": "acc", "ay": "acc", "az": "acc", "gx": "gyr", "gy": "gyr",
        "gz": "gyr", "mx": "mag", "my": "mag", "mz": "mag"}
DEFAULT_UNITS = {"time": "s", "acc": "m/s^2", "gyr": "rad/s", "mag": "uT"}
UNIX_AFTER_S = 1e8


def sniff(source: SourceFile) -> bool:
    return False  # never guessed: the column map says what the columns are


def parse_map(text: str) -> tuple[dict[str, tuple[str, float, float]], str | None]:
    """``--columns`` → {key: (column, sign, factor)} and the sensor column (or None)."""
    entries: dict[str, tuple[str, float, float]] = {}
    sensor = None
    try:
        tokens = shlex.split(text.replace(",", " "))
    except ValueError as exc:
        raise ImportFailure("--columns", f"cannot be split ({exc})") from None
    for token in tokens:
        key, eq, rest = token.partition("=")
        if not eq or not rest:
            raise ImportFailure("--columns", f"{token!r}: expected KEY=COLUMN[:UNIT]")
        if key == "sensor":
            sensor = rest
            continue
        if key not in KEYS:
            raise ImportFailure("--columns", f"unknown key {key!r} (t, ax, ay, az, gx, gy, gz, "
                                "mx, my, mz, sensor)")
        column, _, unit = rest.rpartition(":") if ":" in rest else (rest, "", "")
        sign = -1.0 if column.startswith("-") else 1.0
        column = column.removeprefix("-")
        quantity = KEYS[key]
        factor = unit_factor(unit or DEFAULT_UNITS[quantity], quantity)
        if factor is None:
            raise ImportFailure("--columns", f"{key}: {unit!r} is not a unit of {quantity}")
        entries[key] = (column, sign, factor)
    missing = [k for k in ("t", "ax", "ay", "az", "gx", "gy", "gz") if k not in entries]
    if missing:
        raise ImportFailure("--columns", f"missing {', '.join(missing)}")
    mags = [k for k in ("mx", "my", "mz") if k in entries]
    if mags and len(mags) != 3:
        raise ImportFailure("--columns", "give all of mx, my, mz or none")
    return entries, sensor


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    if not options.columns:
        raise ImportFailure(sources[0].name if sources else "?",
                            "the generic format needs --columns (a column map)")
    entries, sensor_col = parse_map(options.columns)
    return [s for source in sources for s in _read_one(source, entries, sensor_col)]


def _read_one(source, entries, sensor_col) -> list[Signal]:
    lines = text_lines(source)
    header = next((i for i, line in enumerate(lines) if line.strip() and
                   not line.lstrip().startswith("#")), None)
    if header is None:
        raise ImportFailure(source.name, "no header line")
    counts = {d: lines[header].count(d) for d in (",", ";", "\t")}
    delimiter = max(counts, key=counts.get)
    names = split_line(lines[header], delimiter)
    index = {n: i for i, n in enumerate(names)}
    wanted = {}
    for key, (column, _, _) in entries.items():
        if column not in index:
            raise ImportFailure(source.name, f"column {column!r} ({key}) is missing; the "
                                f"header has: {', '.join(names)}", header + 1)
        wanted[key] = index[column]
    values, numbers = numeric_columns(source, lines, header + 1, delimiter, len(names), wanted,
                                      names={k: c for k, (c, _, _) in entries.items()})
    scaled = {k: values[k] * sign * factor for k, (_, sign, factor) in entries.items()
              if k != "t"}
    column, sign, factor = entries["t"]
    scaled["t"] = sign * seconds(values["t"], factor)
    groups = {"": np.arange(len(numbers))}
    if sensor_col:
        if sensor_col not in index:
            raise ImportFailure(source.name, f"sensor column {sensor_col!r} is missing",
                                header + 1)
        labels = np.array([split_line(line, delimiter)[index[sensor_col]]
                           for line in lines[header + 1: header + 1 + len(numbers)]])
        groups = {str(v): np.flatnonzero(labels == v) for v in dict.fromkeys(labels)}
    out = []
    for label, rows in groups.items():
        t = scaled["t"][rows]
        clock = "unix" if len(t) and t[0] > UNIX_AFTER_S else f"file:{source.name}"
        epoch, t = (float(t[0]), t - t[0]) if len(t) else (0.0, t)
        mag = (np.column_stack([scaled[k][rows] for k in ("mx", "my", "mz")])
               if "mx" in scaled else None)
        out.append(Signal(format=NAME, label=label or source.basename, files=(source.name,),
                          t=t, epoch=epoch,
                          acc=np.column_stack([scaled[k][rows] for k in ("ax", "ay", "az")]),
                          gyr=np.column_stack([scaled[k][rows] for k in ("gx", "gy", "gz")]),
                          mag=mag, clock=clock, lines=numbers[rows]))
    return out
