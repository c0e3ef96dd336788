"""MbientLab MetaMotion exports (MetaBase app): one CSV per sensor and signal.

Layout: ``epoc (ms)`` (older apps; ``epoch (ms)`` in newer), a local-time column whose
name holds its UTC offset (``timestamp (-04:00)``, ``time (-13:00)``), ``elapsed (s)``,
then ``x-axis (UNIT),y-axis (UNIT),z-axis (UNIT)``: ``g`` for the accelerometer (×9.80665
→ m/s², specific force: +1 g on the up axis at rest), ``deg/s`` for the gyroscope,
``T`` (or ``µT``) for the magnetometer. Signals of one device are told by the file name
(``…_Accelerometer_…``, ``…_Gyroscope_…``, ``…_Magnetometer_…``; MetaBase names files
``<name>_<date>_<MAC>_<Signal>_<rate>Hz_<version>.csv``) and grouped by the MAC address
in the name. The sensor fusion outputs (Linear Acceleration, Gravity, Quaternion, Euler)
are left out: they are not the raw signals.

Signals at different rates are merged onto the gyroscope's time stamps (linear
interpolation of the accelerometer and magnetometer; samples outside their common span
dropped). Clock: ``epoc (ms)``, UTC (``unix``).
"""

from __future__ import annotations

import re

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .checks import check_one_rate
from .text import head_text, numeric_columns, split_line, text_lines
from .units import unit_factor

NAME = "metamotion"
TITLE = "MbientLab MetaMotion (MetaBase) CSV"
_MAC = re.compile(r"(?<![0-9A-Fa-f])([0-9A-Fa-f]{12})(?![0-9A-Fa-f])")
_AXIS = re.compile(r"([xyz])-axis\s*\((.+)\)")
_FUSED = ("linear", "gravity", "quaternion", "euler", "heading")


def sniff(source: SourceFile) -> bool:
    head = head_text(source, 256).lstrip()
    return head.startswith(("epoc (ms)", "epoch (ms)"))


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    devices: dict[str, dict[str, tuple]] = {}
    for source in sources:
        if not sniff(source):
            continue
        lower = source.basename.lower()
        if any(word in lower for word in _FUSED):
            continue  # sensor-fusion outputs, not raw signals
        kind, values, times, lines, offset = _read_file(source)
        if kind is None:
            continue
        mac = _MAC.search(source.basename)
        device = mac.group(1).upper() if mac else "MetaWear"
        found = devices.setdefault(device, {})
        if kind in found:
            raise ImportFailure(source.name, f"a second {kind} file for device {device} "
                                f"(the first: {found[kind][0].name})")
        found[kind] = (source, times, values, lines, offset)
    if not devices:
        raise ImportFailure(sources[0].name if sources else "?",
                            "no MetaMotion accelerometer, gyroscope or magnetometer files")
    return [_merge(device, parts) for device, parts in devices.items()]


def _read_file(source: SourceFile):
    lines = text_lines(source)
    names = split_line(lines[0], ",")
    axes = {}
    for i, name in enumerate(names):
        m = _AXIS.fullmatch(name)
        if m:
            axes[m.group(1)] = (i, m.group(2))
    if set(axes) != {"x", "y", "z"}:
        return None, None, None, None, None  # not a 3-axis signal (e.g. temperature)
    unit = axes["x"][1]
    kind = next((k for k in ("acc", "gyr", "mag") if unit_factor(unit, k) is not None), None)
    if kind is None:
        raise ImportFailure(source.name, f"x-axis unit {unit!r} is not g, deg/s or T", 1)
    offset = next((n[n.index("(") + 1:-1] for n in names[1:3] if "(" in n and
                   not n.startswith("elapsed")), "")
    wanted = {"t": 0, **{a: axes[a][0] for a in "xyz"}}
    values, numbers = numeric_columns(source, lines, 1, ",", len(names), wanted,
                                      names={k: names[i] for k, i in wanted.items()})
    factor = unit_factor(unit, kind)
    vectors = np.column_stack([values[a] for a in "xyz"]) * factor
    times = values["t"]  # ms since 1970; made relative (exactly) when merged
    probe = Signal(format=NAME, label=source.basename, files=(source.name,), t=times / 1000.0,
                   acc=vectors, gyr=vectors, mag=None, clock="unix", lines=numbers)
    check_one_rate(probe)  # each file's own rate is one rate
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        raise ImportFailure(source.name, "epoc (ms) goes backwards", int(numbers[back[0] + 1]))
    return kind, vectors, times, numbers, offset


def _merge(device: str, parts: dict[str, tuple]) -> Signal:
    for kind, what in (("acc", "Accelerometer"), ("gyr", "Gyroscope")):
        if kind not in parts:
            have = ", ".join(p[0].basename for p in parts.values())
            raise ImportFailure(have, f"device {device}: no {what} file (MetaBase writes one "
                                "file per signal; give all of them, or the folder)")
    gyr_source, ms, gyr, lines, offset = parts["gyr"]
    ref = ms[0]
    parts = {k: (p[0], (p[1] - ref) / 1000.0, *p[2:]) for k, p in parts.items()}
    t = parts["gyr"][1]
    start = max(p[1][0] for p in parts.values())
    end = min(p[1][-1] for p in parts.values())
    keep = (t >= start) & (t <= end)
    t, gyr, lines = t[keep], gyr[keep], lines[keep]
    notes, resampled = [], False
    merged = {}
    acc_source, acc_t, _, acc_numbers, _ = parts["acc"]
    acc_lines = np.round(np.interp(t, acc_t, acc_numbers)).astype(np.int64)
    for kind in ("acc", "mag"):
        if kind not in parts:
            continue
        source, tk, values, _, _ = parts[kind]
        if len(tk) == len(parts["gyr"][1]) and np.array_equal(tk, parts["gyr"][1]):
            merged[kind] = values[keep]
            continue
        merged[kind] = np.column_stack([np.interp(t, tk, values[:, i]) for i in range(3)])
        resampled = True
        rate = 1 / np.median(np.diff(tk))
        notes.append(f"{source.basename}: {rate:.4g} Hz resampled onto the gyroscope's "
                     f"{1 / np.median(np.diff(t)):.4g} Hz time stamps")
    files = (gyr_source.name, *(parts[k][0].name for k in ("acc", "mag") if k in parts))
    signal = Signal(format=NAME, label=device, files=files, t=t, epoch=float(ref) / 1000.0,
                    acc=merged["acc"], gyr=gyr,
                    mag=merged.get("mag"), clock="unix", lines=lines, notes=notes,
                    resampled=resampled, acc_file=acc_source.name, acc_lines=acc_lines)
    if offset:
        signal.metadata["local_time_offset"] = offset
    return signal
