"""Movella (Xsens) DOT CSV exports: one file per sensor.

Layout (Movella DOT app / SDK logger): ``sep=,``, metadata lines ``Key:,value``
(``DeviceTag``, ``FirmwareVersion``, ``AppVersion``, ``SyncStatus``, ``OutputRate``,
``FilterProfile``, ``Measurement Mode``, ``StartTime``), a copyright line, a blank line,
then ``PacketCounter,SampleTimeFine,…``. Read: ``Acc_X..Z`` [m/s², specific force in the
sensor frame: at rest the up axis reads +9.81], ``Gyr_X..Z`` [deg/s → rad/s],
``Mag_X..Z`` [a.u., normalised to the field at the sensor's calibration → × the assumed
field, µT]. ``SampleTimeFine`` [µs, 32-bit, wraps after 2³² µs ≈ 71.6 min] is unwrapped.

Clock: sensors whose ``SyncStatus`` is ``Synced`` share ``SampleTimeFine``
(``xsens-dot-sync``); otherwise each file's ``StartTime`` (UTC after its offset) plus
its own ``SampleTimeFine`` (``unix``, to the StartTime's precision: ms, or s in old
exports). The orientation modes (quaternion, Euler, free acceleration) and the delta
quantities (dq/dv) are refused with the mode to export instead.
"""

from __future__ import annotations

import datetime as dt
import re

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .text import head_text, numeric_columns, split_line, text_lines
from .units import au_to_ut, deg_to_rad

NAME = "xsens-dot"
TITLE = "Movella (Xsens) DOT CSV"
WRAP_US = 2**32
RATE_MODE = "'Rate quantities (with mag)' (or a custom mode with Acc and Gyr)"

_START = re.compile(
    r"(\d{4})-(\d\d)-(\d\d)[ _T](\d\d):(\d\d):(\d\d)(?:[._:](\d{1,6}))?\s*"
    r"(?:(?:GMT|UTC)\s*)?([+-]\d{1,2}(?::?\d\d)?)?")


def sniff(source: SourceFile) -> bool:
    head = head_text(source)
    return "PacketCounter" in head and "SampleTimeFine" in head


def parse_start_time(text: str) -> float | None:
    """A DOT ``StartTime`` as seconds since 1970 UTC, or None: ``2023-01-05 10:22:33.123
    +0100`` (SDK) or ``2021-08-30_17:05:05_000 GMT+8`` (older app)."""
    m = _START.search(text)
    if not m:
        return None
    y, mo, d, h, mi, s = (int(m.group(i)) for i in range(1, 7))
    frac = m.group(7) or "0"
    offset = timedelta_of(m.group(8))
    stamp = dt.datetime(y, mo, d, h, mi, s, tzinfo=dt.timezone(offset))
    return stamp.timestamp() + int(frac) / 10 ** len(frac)


def timedelta_of(text: str | None) -> dt.timedelta:
    if not text:
        return dt.timedelta(0)
    sign = -1 if text[0] == "-" else 1
    digits = text[1:].replace(":", "")
    hours, minutes = (int(digits[:-2]), int(digits[-2:])) if len(digits) > 2 else (int(digits), 0)
    return sign * dt.timedelta(hours=hours, minutes=minutes)


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    return [_read_one(source, options) for source in sources]


def _read_one(source: SourceFile, options: ReadOptions) -> Signal:
    lines = text_lines(source)
    header = next((i for i, line in enumerate(lines) if line.startswith("PacketCounter")), None)
    if header is None:
        raise ImportFailure(source.name, "no PacketCounter,SampleTimeFine,… column line")
    meta: dict[str, str] = {}
    for line in lines[:header]:
        cells = split_line(line, ",")
        if len(cells) >= 2 and cells[0].endswith(":"):
            meta[cells[0].rstrip(":").strip()] = cells[1]
    columns = split_line(lines[header], ",")
    index = {name: i for i, name in enumerate(columns) if name}
    line_no = header + 1
    if "Acc_X" not in index or "Gyr_X" not in index:
        if "dq_W" in index or "dv[1]" in index:
            raise ImportFailure(source.name, "a delta-quantities export (dq/dv): its "
                                "integrated increments are not rates; export with "
                                f"Measurement Mode {RATE_MODE}", line_no)
        found = ", ".join(c for c in columns if c and c not in ("PacketCounter",
                                                                 "SampleTimeFine"))
        raise ImportFailure(source.name, f"an orientation-only export ({found}) has no "
                            "accelerometer and gyroscope rates; export with Measurement Mode "
                            f"{RATE_MODE}", line_no)
    wanted = {"stf": index.get("SampleTimeFine", -1)}
    if wanted["stf"] < 0:
        raise ImportFailure(source.name, "no SampleTimeFine column", line_no)
    for quantity in ("Acc", "Gyr", "Mag"):
        for axis in "XYZ":
            name = f"{quantity}_{axis}"
            if name in index:
                wanted[name] = index[name]
            elif quantity != "Mag":
                raise ImportFailure(source.name, f"column {name} is missing", line_no)
    has_mag = all(f"Mag_{a}" in index for a in "XYZ")
    if not has_mag:
        for a in "XYZ":
            wanted.pop(f"Mag_{a}", None)
    values, numbers = numeric_columns(source, lines, header + 1, ",", len(columns), wanted)
    acc = np.column_stack([values[f"Acc_{a}"] for a in "XYZ"])
    gyr = np.column_stack([values[f"Gyr_{a}"] for a in "XYZ"])
    notes = []
    # The DOT writes a first packet whose rate quantities are all zero (seen in public
    # exports): a sensor cannot read exactly 0 on all six axes, so leading ones are dropped.
    zero = np.flatnonzero(~((acc == 0).all(axis=1) & (gyr == 0).all(axis=1)))
    start = int(zero[0]) if zero.size else len(acc)
    if start:
        notes.append(f"{source.basename}: dropped {start} leading packet(s) with all "
                     "rates exactly 0")
    stf = values["stf"][start:]
    if np.any(stf < 0) or np.any(stf >= WRAP_US) or np.any(stf != np.floor(stf)):
        bad = int(np.flatnonzero((stf < 0) | (stf >= WRAP_US) | (stf != np.floor(stf)))[0])
        raise ImportFailure(source.name, "SampleTimeFine is not a 32-bit count of µs",
                            int(numbers[start + bad]))
    steps = np.diff(stf)
    steps[steps < -WRAP_US / 2] += WRAP_US  # the 32-bit counter wrapped
    micros = stf[0] + np.concatenate([[0.0], np.cumsum(steps)])
    mag = None
    if has_mag:
        mag = au_to_ut(np.column_stack([values[f"Mag_{a}"] for a in "XYZ"])[start:],
                       options.field_ut)
        notes.append(f"{source.basename}: magnetometer a.u. taken as {options.field_ut:g} µT "
                     "(DOT normalises it to the field at its calibration)")
    rate = meta.get("OutputRate", "")
    declared = float(rate.lower().removesuffix("hz")) if re.fullmatch(
        r"\d+(\.\d+)?\s*[Hh]z", rate) else None
    t = (micros - micros[0]) / 1e6
    if meta.get("SyncStatus", "").lower() == "synced":
        clock, epoch = "xsens-dot-sync", micros[0] / 1e6
    else:
        start_time = parse_start_time(meta.get("StartTime", ""))
        if start_time is None:
            clock, epoch = f"file:{source.name}", 0.0
        else:
            clock, epoch = "unix", start_time
            notes.append(f"{source.basename}: not synced; placed by its StartTime "
                         f"{meta.get('StartTime')}")
    label = meta.get("DeviceTag") or source.basename.rsplit(".", 1)[0]
    return Signal(format=NAME, label=label, files=(source.name,), t=t, acc=acc[start:],
                  gyr=deg_to_rad(gyr[start:]), mag=mag, clock=clock, lines=numbers[start:],
                  declared_rate_hz=declared, notes=notes, epoch=epoch,
                  metadata={k: v for k, v in meta.items() if k in (
                      "DeviceTag", "FirmwareVersion", "FilterProfile", "Measurement Mode")})
