"""Writing recording files (``docs/spec/recording.md``, version 1).

The header lines come in the spec's order (version, side, height_m, lengths_m,
calibration, marks, rate_hz, then metadata in its order), then the column line, then
the rows of all sensors merged by ``t`` (stable: a sensor's rows keep their order, ties
between sensors go in ``SENSOR_NAMES`` order). Floats are written as the shortest text
that reads back as the same float64 (Arrow's float formatter, e.g. ``1``, ``0.1``,
``5e-324``); a 6-axis sensor's ``mx my mz`` are empty. Lines end in LF, no BOM.

A recording that would break the spec is refused (:func:`check_recording`) before a
byte is written; a file is written to a temporary name next to it and renamed over the
target, so a crash never leaves half a file.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from ..body import SENSOR_NAMES
from ..errors import EstimatorError, InvalidRecording
from .header import format_header
from .model import Recording, SensorStream, check_metadata
from .points import check_points, format_points
from .rules import COLUMNS, backwards_message, beyond_range, range_message

_WRITE = pacsv.WriteOptions(include_header=False, quoting_style="none", batch_size=1 << 16)
_NAMES = pa.array(SENSOR_NAMES, pa.string())
_MIN_SLICE = 50_000  # rows; below it, threads cost more than they save


def check_recording(recording: Recording) -> None:
    """Refuse (InvalidRecording, no line) a recording whose file would break the spec:
    an unknown sensor, no samples, a non-finite value, a norm beyond the physical range,
    ``t`` going backwards, or metadata a header line cannot carry."""
    if not recording.sensors:
        raise InvalidRecording("a recording needs at least one sensor with samples")
    for name, stream in recording.sensors.items():
        if name not in SENSOR_NAMES:
            raise InvalidRecording(f"unknown sensor {name!r}")
        _check_stream(name, stream)
    for key, value in recording.metadata.items():
        try:
            check_metadata(key, value)
        except EstimatorError as exc:
            raise InvalidRecording(str(exc)) from None
    check_points(recording.points)


def _check_stream(name: str, stream: SensorStream) -> None:
    if len(stream) == 0:
        raise InvalidRecording(f"sensor {name} has no samples")
    parts = {"t": stream.t[:, None], "acc": stream.acc, "gyr": stream.gyr}
    if stream.mag is not None:
        parts["mag"] = stream.mag
    for quantity, values in parts.items():
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise InvalidRecording(f"sensor {name}, sample {i}: {quantity} is not finite")
        if quantity != "t":
            with np.errstate(over="ignore"):
                bad = np.flatnonzero(beyond_range(quantity, *values.T))
            if bad.size:
                i = int(bad[0])
                message = range_message(quantity, name, values[i])
                raise InvalidRecording(f"sample {i}: {message}")
    back = np.flatnonzero(stream.t[1:] < stream.t[:-1])
    if back.size:
        i = int(back[0]) + 1
        message = backwards_message(name, stream.t[i], stream.t[i - 1])
        raise InvalidRecording(f"sample {i}: {message}")


def format_recording(recording: Recording) -> bytes:
    """The bytes of the recording file; refuses a recording that breaks the spec."""
    return b"".join(_parts(recording))


def write_recording_to(recording: Recording, out: BinaryIO) -> None:
    """Write the recording file's bytes to the binary file ``out`` piece by piece (no
    joined copy); refuses a recording that breaks the spec before a byte is written."""
    for part in _parts(recording):
        out.write(part)


def write_recording(recording: Recording, path: str | os.PathLike[str]) -> None:
    """Write the recording file at ``path`` atomically (temporary file, then rename),
    readable by its owner only (0600): a recording is a patient's data."""
    parts = _parts(recording)
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with open(fd, "wb", closefd=True) as f:
            for part in parts:
                f.write(part)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable where possible
        directory = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)


def _parts(recording: Recording) -> list[bytes | memoryview]:
    """The file's bytes in pieces: the header, then the rows merged by time."""
    check_recording(recording)
    parts = [format_header(recording).encode("utf-8"), *_rows(recording)]
    if recording.points:
        parts.append(format_points(recording.points))
    return parts


def _rows(recording: Recording) -> list[memoryview]:
    """The data rows, merged by time, as CSV text in slices."""
    streams = [(name, recording.sensors[name]) for name in SENSOR_NAMES
               if name in recording.sensors]  # ties between sensors go in this order
    n = sum(len(s) for _, s in streams)
    values = np.empty((n, 10))
    codes = np.empty(n, dtype=np.int8)
    six_axis = np.zeros(n, dtype=bool)
    at = 0
    for name, s in streams:
        rows = slice(at, at + len(s))
        values[rows, 0] = s.t
        values[rows, 1:4] = s.acc
        values[rows, 4:7] = s.gyr
        if s.mag is None:
            values[rows, 7:10] = 0.0
            six_axis[rows] = True
        else:
            values[rows, 7:10] = s.mag
        codes[rows] = SENSOR_NAMES.index(name)
        at += len(s)
    order = np.argsort(values[:, 0], kind="stable")
    values, codes, six_axis = values[order].T.copy(), codes[order], six_axis[order]
    mask = six_axis if six_axis.any() else None
    columns = [pa.array(values[0]), pa.DictionaryArray.from_arrays(pa.array(codes), _NAMES)]
    columns += [pa.array(v) for v in values[1:7]]
    columns += [pa.array(v, mask=mask) for v in values[7:]]
    table = pa.table(columns, names=list(COLUMNS))
    # Formatting floats is the cost; Arrow releases the GIL, so slices format in parallel.
    workers = min(os.cpu_count() or 1, n // _MIN_SLICE)
    if workers < 2:
        return [_csv(table)]
    step = -(-n // workers)
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(_csv, (table.slice(i, step) for i in range(0, n, step))))


def _csv(table: pa.Table) -> memoryview:
    sink = pa.BufferOutputStream()
    pacsv.write_csv(table, sink, _WRITE)
    return memoryview(sink.getvalue())
