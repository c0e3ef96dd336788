"""Sensor Logger (phone app, iOS and Android) zip/folder exports.

Files read (by name, case-insensitive; others such as Location.csv are left out):
``Gyroscope.csv`` [rad/s], ``TotalAcceleration.csv`` (Android: with gravity) or
``Accelerometer.csv`` (without gravity) plus ``Gravity.csv`` [m/s²], ``Magnetometer.csv``
[µT], and ``Metadata.csv`` (``platform``; its start time). Each data file is
``time,seconds_elapsed,z,y,x`` with ``time`` in ns since 1970 UTC; columns are read by
name.

Signs: on Android (and with "Standardise Units & Frames" on) the accelerations follow the
right-handed "accelerating force" convention, gravity +z flat on a table: the specific
force is ``TotalAcceleration`` or ``Accelerometer + Gravity``. On iOS (the setting off,
its default) all three axes of Accelerometer and Gravity are negated: the specific force
is ``−(Accelerometer + Gravity)``. The gyroscope agrees on both. The platform comes from
Metadata.csv, or ``ReadOptions.platform``; a metadata column whose name holds
"standardis(z)e" and reads true marks the setting.

The signals are merged onto the gyroscope's time stamps (linear interpolation; the
phone's sensors are not sampled together).
"""

from __future__ import annotations

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .checks import check_one_rate
from .text import head_text, numeric_columns, split_line, text_lines

NAME = "sensor-logger"
TITLE = "Sensor Logger (phone app) export"
DATA_FILES = ("gyroscope.csv", "accelerometer.csv", "gravity.csv", "totalacceleration.csv",
              "magnetometer.csv")
META_FILES = ("metadata.csv",)


def sniff(source: SourceFile) -> bool:
    name = source.basename.lower()
    head = head_text(source, 128).lstrip()
    return ((name in DATA_FILES and head.startswith("time,seconds_elapsed"))
            or (name in META_FILES and head.startswith("version,")))


def _metadata(source: SourceFile) -> dict[str, str]:
    lines = [line for line in text_lines(source) if line.strip()]
    if len(lines) < 2:
        raise ImportFailure(source.name, "no values under the metadata header", 1)
    keys = split_line(lines[0], ",")
    values = split_line(lines[1], ",")
    return {k.lower(): v for k, v in zip(keys, values, strict=False)}


def _vectors(source: SourceFile) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lines = text_lines(source)
    names = split_line(lines[0], ",")
    index = {n: i for i, n in enumerate(names)}
    for need in ("time", "x", "y", "z"):
        if need not in index:
            raise ImportFailure(source.name, f"column {need} is missing", 1)
    wanted = {k: index[k] for k in ("time", "x", "y", "z")}
    values, numbers = numeric_columns(source, lines, 1, ",", len(names), wanted,
                                      integers=frozenset({"time"}))
    t = values["time"] / 1e9  # s since 1970 for the merge; exact spacing kept below
    xyz = np.column_stack([values[a] for a in "xyz"])
    probe = Signal(format=NAME, label=source.basename, files=(source.name,), t=t, acc=xyz,
                   gyr=xyz, mag=None, clock="unix", lines=numbers)
    check_one_rate(probe)
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        raise ImportFailure(source.name, "time goes backwards", int(numbers[back[0] + 1]))
    return values["time"], xyz, numbers  # raw ns (int64 when whole numbers)


def _onto(t: np.ndarray, tk: np.ndarray, values: np.ndarray) -> np.ndarray:
    if len(tk) == len(t) and np.array_equal(tk, t):
        return values
    return np.column_stack([np.interp(t, tk, values[:, i]) for i in range(3)])


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    by_name = {}
    for s in sources:
        if sniff(s):
            by_name.setdefault(s.basename.lower(), s)
    where = ", ".join(s.name for s in sources[:2]) or "?"
    meta = _metadata(by_name["metadata.csv"]) if "metadata.csv" in by_name else {}
    platform = (options.platform or meta.get("platform", "")).lower()
    standardised = platform == "standardised" or any(
        "standardi" in k and v.lower() in ("true", "1", "yes", "on") for k, v in meta.items())
    if not platform:
        raise ImportFailure(where, "no Metadata.csv naming the platform (iOS and Android "
                            "accelerations differ in sign): add it, or give --platform")
    if platform not in ("ios", "android", "standardised"):
        raise ImportFailure(where, f"unknown platform {platform!r} (ios or android)")
    if "gyroscope.csv" not in by_name:
        raise ImportFailure(where, "no Gyroscope.csv")
    raw, gyr, lines = _vectors(by_name["gyroscope.csv"])
    ref = raw[0]  # every file's ns made relative to the gyroscope's first, exactly

    def relative(ns):
        return (ns - ref) / 1e9

    t = relative(raw)
    files = [by_name["gyroscope.csv"].name]
    parts = {}
    for name in ("totalacceleration.csv", "accelerometer.csv", "gravity.csv",
                 "magnetometer.csv"):
        if name in by_name:
            ns, xyz, numbers = _vectors(by_name[name])
            parts[name] = (relative(ns), xyz, numbers)
    if "totalacceleration.csv" in parts:
        used = ["totalacceleration.csv"]
    elif "accelerometer.csv" in parts and "gravity.csv" in parts:
        used = ["accelerometer.csv", "gravity.csv"]
    elif "accelerometer.csv" in parts:
        used = ["accelerometer.csv"]  # refused by the gravity check if it excludes gravity
    else:
        raise ImportFailure(where, "no TotalAcceleration.csv or Accelerometer.csv")
    spans = [parts[n][0] for n in used] + ([parts["magnetometer.csv"][0]]
                                           if "magnetometer.csv" in parts else [])
    start, end = max([t[0], *(s[0] for s in spans)]), min([t[-1], *(s[-1] for s in spans)])
    keep = (t >= start) & (t <= end)
    t, gyr, lines = t[keep], gyr[keep], lines[keep]
    force = sum(_onto(t, parts[n][0], parts[n][1]) for n in used)
    acc_lines = np.round(np.interp(t, parts[used[0]][0], parts[used[0]][2])).astype(np.int64)
    notes = [f"Sensor Logger {platform}{' (standardised frames)' if standardised else ''}: "
             f"specific force from {' + '.join(by_name[n].basename for n in used)}"]
    if platform == "ios" and not standardised:
        force = -force
        notes.append("iOS accelerations negated to the right-handed convention")
    files += [by_name[n].name for n in used]
    mag = None
    if "magnetometer.csv" in parts:
        mag = _onto(t, parts["magnetometer.csv"][0], parts["magnetometer.csv"][1])
        files.append(by_name["magnetometer.csv"].name)
    label = meta.get("device name") or "phone"
    return [Signal(format=NAME, label=label, files=tuple(files), t=t, epoch=float(ref) / 1e9,
                   acc=force, gyr=gyr,
                   mag=mag, clock="unix", lines=lines, notes=notes, resampled=True,
                   acc_file=by_name[used[0]].name, acc_lines=acc_lines,
                   metadata={"platform": platform})]
