"""Shimmer (Consensys) CSV exports: one or several Shimmer devices per file.

Layout: a separator line (``"sep=\\t"``, ``sep=,``, ``"sep=;"``), a line of signal names
``<Device>_<Signal>_CAL`` (e.g. ``Shimmer_40AC_Accel_LN_X_CAL``), optionally a line of
``CAL``/``RAW`` formats, a units row, then the samples. Read per device: the time stamp
``Timestamp_Unix_CAL`` (or ``TimestampSync_Unix_CAL``) [ms since 1970 UTC], the low-noise
accelerometer ``Accel_LN_*`` (or, without it, the wide-range ``Accel_WR_*``) [m/(s^2)],
``Gyro_*`` [deg/s] and ``Mag_*`` [the units row decides: ``local_flux`` is read as gauss,
also ``uT``, ``T``, ``Ga``]. Every unit comes from the units row, never assumed; a row that
lies is caught by the plausibility check (|a| at rest near 9.81).
"""

from __future__ import annotations

import re

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .text import head_text, numeric_columns, split_line, text_lines
from .units import seconds, unit_factor

NAME = "shimmer"
TITLE = "Shimmer Consensys CSV"

_COLUMN = re.compile(
    r"(?P<device>.+?)_(?P<signal>Timestamp_Unix|TimestampSync_Unix|Accel_LN_[XYZ]|"
    r"Accel_WR_[XYZ]|Gyro_[XYZ]|Mag_[XYZ])_(?:CAL|UNCAL)$")
_TIMES = ("Timestamp_Unix", "TimestampSync_Unix")


def sniff(source: SourceFile) -> bool:
    head = head_text(source)
    first = head.split("\n", 1)[0].strip().strip('"')
    return first.startswith("sep=") and "_CAL" in head


def delimiter_of(first_line: str) -> str:
    text = first_line.strip().strip('"')
    if not text.startswith("sep="):
        raise ValueError("no sep= line")
    sep = text[4:5]
    return sep or "\t"


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    return [signal for source in sources for signal in _read_file(source)]


def _read_file(source: SourceFile) -> list[Signal]:
    lines = text_lines(source)
    try:
        delimiter = delimiter_of(lines[0])
    except (ValueError, IndexError):
        raise ImportFailure(source.name, "no sep= line first", 1) from None
    if len(lines) < 3:
        raise ImportFailure(source.name, "no signal names and units rows", len(lines))
    names = split_line(lines[1], delimiter)
    row = 2
    if all(c.upper() in ("CAL", "RAW", "UNCAL", "") for c in split_line(lines[2], delimiter)):
        row = 3  # the formats row
    if row >= len(lines):
        raise ImportFailure(source.name, "no units row", row + 1)
    units = split_line(lines[row], delimiter)
    devices: dict[str, dict[str, int]] = {}
    for i, name in enumerate(names):
        m = _COLUMN.fullmatch(name)
        if m:
            devices.setdefault(m.group("device"), {})[m.group("signal")] = i
    if not devices:
        raise ImportFailure(source.name, "no Shimmer calibrated columns "
                            "(<Device>_Accel_LN_X_CAL, …_Gyro_X_CAL, …_Timestamp_Unix_CAL)", 2)
    width = max(len(names), len(units))
    return [_device(source, lines, row, delimiter, width, names, units, dev, cols)
            for dev, cols in devices.items()]


def _device(source, lines, units_row, delimiter, width, names, units, device, cols):
    line_units = units_row + 1
    time_key = next((k for k in _TIMES if k in cols), None)
    if time_key is None:
        raise ImportFailure(source.name, f"{device}: no {device}_Timestamp_Unix_CAL column "
                            "(export the Unix time stamp)", 2)
    accel = "Accel_LN" if all(f"Accel_LN_{a}" in cols for a in "XYZ") else "Accel_WR"
    wanted = {"t": cols[time_key]}
    for prefix in (accel, "Gyro"):
        for a in "XYZ":
            if f"{prefix}_{a}" not in cols:
                missing = "Accel_LN_X" if prefix == "Accel_WR" else f"{prefix}_{a}"
                raise ImportFailure(source.name,
                                    f"column {device}_{missing}_CAL is missing", 2)
            wanted[f"{prefix}_{a}"] = cols[f"{prefix}_{a}"]
    has_mag = all(f"Mag_{a}" in cols for a in "XYZ")
    if has_mag:
        wanted.update({f"Mag_{a}": cols[f"Mag_{a}"] for a in "XYZ"})
    factors = {}
    for key, index in wanted.items():
        quantity = {"t": "time", "Gyro": "gyr", "Mag": "mag"}.get(key.split("_")[0], "acc")
        unit = units[index] if index < len(units) else ""
        factor = unit_factor(unit, quantity)
        if factor is None:
            raise ImportFailure(source.name, f"{names[index]}: unit {unit!r} in the units row "
                                f"is not a unit of {_WHAT[quantity]}", line_units)
        factors[key] = factor
    values, numbers = numeric_columns(source, lines, units_row + 1, delimiter,
                                      min(width, len(names)), wanted,
                                      names={k: names[i] for k, i in wanted.items()})

    def vector(prefix):
        return np.column_stack([values[f"{prefix}_{a}"] * factors[f"{prefix}_{a}"]
                                for a in "XYZ"])

    notes = [f"{source.basename}: {device} accelerometer "
             + ("low-noise (Accel_LN)" if accel == "Accel_LN" else "wide-range (Accel_WR)")]
    stamps = values["t"]
    return Signal(format=NAME, label=device, files=(source.name,),
                  epoch=float(seconds(stamps[0], factors["t"])),
                  t=seconds(stamps - stamps[0], factors["t"]), acc=vector(accel),
                  gyr=vector("Gyro"),
                  mag=vector("Mag") if has_mag else None, clock="unix", lines=numbers,
                  notes=notes)


_WHAT = {"time": "time (ms, s)", "acc": "acceleration (m/(s^2), g)",
         "gyr": "angular rate (deg/s, rad/s)", "mag": "magnetic field (local_flux, uT, T, Ga)"}
