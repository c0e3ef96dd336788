"""Vendor files → a strict recording: detect each file's format, read the sensors in it,
put all sensors on one clock, check them, and build the
:class:`~armtrack.estimator.recording.Recording` (``docs/spec/recording.md``)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from types import ModuleType

import numpy as np

from ..body import SENSOR_NAMES
from ..errors import EstimatorError
from ..recording import Recording, SensorStream
from ..recording.header import parse_calibration
from .base import ImportFailure, ReadOptions, Signal, SourceFile
from .checks import check_signal
from .poses import propose_calibration


def formats() -> dict[str, ModuleType]:
    """The readers by name, in the order formats are tried when detecting."""
    from . import apdm, generic, metamotion, sensor_logger, shimmer, xsens_dot

    return {m.NAME: m for m in (xsens_dot, shimmer, metamotion, sensor_logger, apdm, generic)}


def detect(sources: list[SourceFile]) -> str:
    """The format of a group of files (all must be one format; files no reader knows in a
    folder or zip are left out by the readers that take folders)."""
    readers = formats()
    found = {}
    for source in sources:
        name = next((n for n, m in readers.items() if n != "generic" and m.sniff(source)), None)
        if name:
            found.setdefault(name, source.name)
    if not found:
        names = ", ".join(s.name for s in sources[:3])
        raise ImportFailure(names, "not a format armtrack knows (" + ", ".join(
            m.TITLE for m in readers.values()) + "); give --format generic with --columns")
    if len(found) > 1:
        detail = "; ".join(f"{f} is {n}" for n, f in found.items())
        raise ImportFailure(next(iter(found.values())),
                            f"files of different formats for one sensor ({detail})")
    return next(iter(found))


DEFAULT_OPTIONS = ReadOptions()


def read_signals(sources: list[SourceFile], format_name: str | None = None,
                 options: ReadOptions = DEFAULT_OPTIONS) -> list[Signal]:
    """Every sensor found in ``sources`` (read as ``format_name`` or the detected one)."""
    readers = formats()
    name = format_name or detect(sources)
    if name not in readers:
        raise ImportFailure(sources[0].name if sources else "?", f"unknown format {name!r}; "
                            f"one of {', '.join(readers)}")
    return readers[name].read(sources, options)


def pick(signals: list[Signal], label: str | None, what: str) -> Signal:
    """The signal ``label`` names (a vendor label, device id, or any unique part of it),
    or the only one."""
    if label is None:
        if len(signals) == 1:
            return signals[0]
        labels = ", ".join(s.label for s in signals)
        raise ImportFailure(what, f"holds {len(signals)} sensors ({labels}); name one "
                            "with FILE:LABEL")
    exact = [s for s in signals if s.label == label]
    if len(exact) == 1:
        return exact[0]
    partial = [s for s in signals if label.lower() in s.label.lower()]
    if len(partial) == 1:
        return partial[0]
    labels = ", ".join(s.label for s in signals)
    raise ImportFailure(what, f"no single sensor labelled {label!r} (found: {labels})")


@dataclass
class Assignment:
    """Files of one recording sensor: ``sensor`` (trunk … hand), its files, the vendor
    label inside them, and the format if not detected."""

    sensor: str
    sources: list[SourceFile]
    label: str | None = None
    format: str | None = None


@dataclass
class ImportResult:
    recording: Recording
    signals: dict[str, Signal]
    notes: list[str] = field(default_factory=list)
    #: still periods that look like the poses, as a ``calibration`` value (or None)
    proposal: str | None = None


def import_recording(assignments: list[Assignment], side: str, height_m: float | None = None,
                     calibration: str | None = None, options: ReadOptions = DEFAULT_OPTIONS,
                     lengths=None) -> ImportResult:
    """Read, check and assemble. ``calibration``: a ``calibration`` header value, ``auto``
    (the proposal, when one is found) or None (no poses; the proposal is returned)."""
    seen = {}
    for a in assignments:
        if a.sensor not in SENSOR_NAMES:
            raise ImportFailure(a.sources[0].name if a.sources else a.sensor,
                                f"unknown sensor {a.sensor!r} (one of {', '.join(SENSOR_NAMES)})")
        if a.sensor in seen:
            raise ImportFailure(a.sensor, "sensor given twice; give several files of one "
                                "sensor as SENSOR=FILE SENSOR=FILE (they are grouped)")
        seen[a.sensor] = a
    signals: dict[str, Signal] = {}
    for a in assignments:
        found = read_signals(a.sources, a.format, options)
        what = ", ".join(s.name for s in a.sources)
        signal = pick(found, a.label, what)
        check_signal(signal)
        signals[a.sensor] = signal
    streams, notes, metadata = place_on_clock(signals)
    poses = ()
    proposal = propose_calibration(streams)
    if calibration == "auto":
        if proposal is None:
            raise ImportFailure(", ".join(s.files[0] for s in signals.values()),
                                "no still periods that look like the N-pose and T-pose; "
                                "give --calibration \"npose START END; tpose START END\"")
        calibration = proposal
    if calibration:
        try:
            poses = tuple(parse_calibration(calibration, None))
        except EstimatorError as exc:
            raise ImportFailure("--calibration", str(exc)) from None
    rates = [s.rate_hz for s in signals.values()]
    rate = round(float(np.median(rates)), 3) if rates else None
    formats_used = sorted({s.format for s in signals.values()})
    metadata = {"import_format": ", ".join(formats_used), **metadata}
    for sensor, s in signals.items():
        names = "; ".join(f.replace("\\", "/").rsplit("/", 1)[-1] for f in s.files)
        metadata[f"import_{sensor}"] = " ".join(f"{s.label} from {names}".split())
    try:
        recording = Recording(side=side, sensors=streams, height_m=height_m, lengths=lengths,
                              calibration=poses, rate_hz=rate, metadata=metadata)
    except EstimatorError as exc:
        raise ImportFailure("import", str(exc)) from None
    for s in signals.values():
        notes.extend(s.notes)
    return ImportResult(recording=recording, signals=signals, notes=notes, proposal=proposal)


def place_on_clock(signals: dict[str, Signal]) -> tuple[dict[str, SensorStream], list[str],
                                                        dict[str, str]]:
    """Streams on one clock starting at 0 s: the first sample of any sensor."""
    clocks = {s.clock for s in signals.values()}
    if len(clocks) > 1:
        detail = "; ".join(f"{n}: {s.clock}" for n, s in signals.items())
        raise ImportFailure(", ".join(s.files[0] for s in signals.values()),
                            f"the sensors' times are on different clocks ({detail}); "
                            "import files that share a clock (synced or time-stamped)")
    starts = {n: s.epoch + float(s.t[0]) for n, s in signals.items()}
    ends = {n: s.epoch + float(s.t[-1]) for n, s in signals.items()}
    t0 = min(starts.values())
    late = max(starts, key=starts.get)
    early_end = min(ends, key=ends.get)
    if starts[late] > ends[early_end]:
        raise ImportFailure(signals[late].files[0], f"sensor {late} starts "
                            f"{starts[late] - ends[early_end]:.1f} s after {early_end} ends: "
                            "the files are not of one session")
    notes, metadata = [], {}
    clock = next(iter(clocks))
    if clock == "unix":
        stamp = dt.datetime.fromtimestamp(t0, dt.UTC)
        metadata["start_utc"] = stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z")
        notes.append(f"one clock: the vendors' UTC time stamps; 0 s is {metadata['start_utc']}")
    elif clock.startswith("file:"):
        notes.append("one sensor on its file's own clock (no absolute time)")
    else:
        notes.append(f"one clock: {clock}")
    for n in signals:
        if starts[n] - t0 > 0.5:
            notes.append(f"{n} starts {starts[n] - t0:.2f} s after the first sensor")
    # the offset first (small), then the exact relative times: no float64 jitter
    streams = {n: SensorStream(t=(s.epoch - t0) + s.t, acc=s.acc, gyr=s.gyr, mag=s.mag)
               for n, s in signals.items()}
    return streams, notes, metadata


def describe(signal: Signal) -> dict:
    """What the upload dialog shows of a sensor found in files."""
    return {"format": signal.format, "label": signal.label, "files": list(signal.files),
            "rate_hz": round(signal.rate_hz, 2), "duration_s": round(signal.duration_s, 2),
            "samples": len(signal), "axes": 9 if signal.mag is not None else 6,
            "clock": signal.clock,
            "start": signal.epoch + float(signal.t[0]) if len(signal) else None,
            "notes": list(signal.notes)}
