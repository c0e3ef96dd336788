"""Checks every imported sensor passes before anything is written or stored: time order,
one rate per file, a declared rate that matches the time stamps, the physical ranges of
``docs/spec/recording.md``, and plausibility (|a| at rest near 9.81 m/s²: catches a units row
that lies, and an "accelerometer" without gravity)."""

from __future__ import annotations

import numpy as np

from ..recording.rules import beyond_range, range_message
from .base import ImportFailure, Signal
from .units import STANDARD_GRAVITY

#: A file whose rate changes by more than this share part-way is refused (mixed rates).
RATE_TOLERANCE = 0.15
#: Samples per block when looking for a rate change (block medians ignore lost samples
#: and time-stamp jitter).
RATE_BLOCK = 50
#: |a| at rest must be within this share of standard gravity.
GRAVITY_TOLERANCE = 0.2
#: Angular rate [rad/s] below which a sample counts as still for the gravity check.
STILL_RATE = 0.15


def line_of(signal: Signal, i: int) -> int | None:
    line = int(signal.lines[i]) if len(signal.lines) > i else 0
    return line or None


def failure(signal: Signal, problem: str, i: int | None = None) -> ImportFailure:
    """An ImportFailure naming the signal's file and sample ``i``'s line (or sample)."""
    return ImportFailure(signal.files[0], problem, None if i is None else line_of(signal, i),
                         signal.place)


def check_signal(signal: Signal) -> None:
    """Refuse (ImportFailure naming file and line) what would make a wrong recording."""
    if len(signal) < 2:
        raise failure(signal, f"sensor {signal.label} has {len(signal)} sample(s); "
                      "a recording needs more")
    back = np.flatnonzero(np.diff(signal.t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise failure(signal, f"time goes backwards ({signal.t[i]!r} s after "
                      f"{signal.t[i - 1]!r} s on its clock)", i)
    for quantity, values in (("acc", signal.acc), ("gyr", signal.gyr), ("mag", signal.mag)):
        if values is None:
            continue
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            raise failure(signal, f"{quantity} is not finite", int(bad[0]))
        with np.errstate(over="ignore"):
            bad = np.flatnonzero(beyond_range(quantity, *values.T))
        if bad.size:
            i = int(bad[0])
            raise failure(signal, range_message(quantity, signal.label, values[i])
                          + " (is the unit right?)", i)
    if not signal.resampled:
        check_one_rate(signal)
    check_gravity(signal)


def check_one_rate(signal: Signal) -> None:
    """Refuse a file whose sample rate changes part-way, or that declares another rate."""
    dt = np.diff(signal.t)
    positive = dt[dt > 0]
    if not positive.size:
        raise failure(signal, "all time stamps are equal", 0)
    nominal = float(np.median(positive))
    blocks = len(dt) // RATE_BLOCK
    if blocks >= 2:
        nominal = float(np.median(dt[:RATE_BLOCK]))  # the rate the file starts with
        medians = np.median(dt[: blocks * RATE_BLOCK].reshape(blocks, RATE_BLOCK), axis=1)
        off = np.flatnonzero(np.abs(medians / nominal - 1.0) > RATE_TOLERANCE)
        if off.size:
            b = int(off[0])
            block = dt[b * RATE_BLOCK:(b + 1) * RATE_BLOCK]
            i = b * RATE_BLOCK + int(np.argmax(np.abs(block / nominal - 1.0) > RATE_TOLERANCE))
            raise failure(signal, f"the sample rate changes from {1 / nominal:.4g} Hz to "
                          f"{1 / float(medians[b]):.4g} Hz (mixed rates in one file: "
                          "export each rate on its own)", i + 1)
    declared = signal.declared_rate_hz
    if declared and abs((1.0 / nominal) / declared - 1.0) > RATE_TOLERANCE:
        raise failure(signal, f"the file declares {declared:g} Hz but its time stamps are "
                      f"{1 / nominal:.4g} Hz apart")


def check_gravity(signal: Signal) -> None:
    """|a| at rest must be near standard gravity: a unit row that says m/s² over values in
    g reads ~1, an accelerometer without gravity ~0."""
    norm = np.linalg.norm(signal.acc, axis=1)
    still = np.linalg.norm(signal.gyr, axis=1) < STILL_RATE
    at_rest = norm[still] if still.sum() >= max(10, len(norm) // 50) else norm
    typical = float(np.median(at_rest))
    if abs(typical / STANDARD_GRAVITY - 1.0) > GRAVITY_TOLERANCE:
        first = int(np.flatnonzero(still)[0]) if still.any() else 0
        hint = ("values look like g, not m/s²" if 0.6 < typical < 1.6 else
                "the accelerometer excludes gravity" if typical < 0.6 else
                "the unit is wrong")
        problem = (f"sensor {signal.label}: |a| at rest is {typical:.3g} m/s², not near 9.81 "
                   f"({hint})")
        if signal.acc_file and signal.acc_lines is not None:
            raise ImportFailure(signal.acc_file, problem, int(signal.acc_lines[first]) or None)
        raise failure(signal, problem, first)
