"""The device's messages of ``docs/spec/ingest.md`` built from a recording, in sending order.

A :class:`MessagePlan` fixes, before anything is sent, every ``samples`` and ``mark``
message of a recording, its ``seq`` and the time on the recording's clock [s] when a
real kit would send it: a ``samples`` message when its last row has been sampled, a
``mark`` when the clock reaches its ``t``. Messages are built (and JSON-encoded) only
when asked for, so a long recording costs its arrays, not a million dicts.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.recording import Mark, Recording
from armtrack.estimator.recording.model import GYRO_DELAY_KEY

PROTOCOL_VERSION = 1
#: Rows a ``samples`` message may carry (``docs/spec/ingest.md``).
MAX_ROWS_PER_MESSAGE = 1000

_SAMPLES, _MARK = 0, 1  # message kinds; at equal send times samples go before marks


def encode(message: dict[str, Any]) -> str:
    """One message as compact JSON text. Floats use Python's shortest repr, which parses
    back to the same float64; NaN and infinities are refused (``ValueError``)."""
    return json.dumps(message, allow_nan=False, separators=(",", ":"))


def recording_marks(recording: Recording) -> list[Mark]:
    """The marks a kit sends for ``recording``: each calibration pose as ``NAME`` at its
    start and ``end:NAME`` at its end, then the recording's own marks, sorted by ``t``
    (stable, so equal times keep this order)."""
    marks = [m for p in recording.calibration
             for m in (Mark(p.start, p.name), Mark(p.end, f"end:{p.name}"))]
    marks.extend(recording.marks)
    return sorted(marks, key=lambda m: m.t)


def nominal_rate(recording: Recording) -> float:
    """The recording's ``rate_hz`` [Hz], or else 1 / the median sample interval over all
    sensors; refuses a recording with no sensor holding two distinct sample times."""
    if recording.rate_hz is not None:
        return recording.rate_hz
    steps = np.concatenate([np.diff(s.t) for s in recording.sensors.values()] or [[]])
    steps = steps[steps > 0]
    if not len(steps):
        raise InvalidArgument("cannot tell the sample rate: give rate_hz")
    return float(1.0 / np.median(steps))


def hello_message(recording: Recording, device: str, resume: str | None = None,
                  rate_hz: float | None = None) -> dict[str, Any]:
    """The ``hello`` for ``recording``: protocol 1, its side and sensors (in the
    recording's order), ``rate_hz`` [Hz] (default :func:`nominal_rate`), ``nine_axis``
    and ``resume`` (the stream id of an earlier connection, or None); the file's
    declared ``gyro_delay_s`` [s] and wrist points, when it has them."""
    hello = {
        "type": "hello", "protocol": PROTOCOL_VERSION, "device": device,
        "side": recording.side, "sensors": list(recording.sensors),
        "rate_hz": nominal_rate(recording) if rate_hz is None else float(rate_hz),
        "nine_axis": _nine_axis(recording), "resume": resume,
    }
    if GYRO_DELAY_KEY in recording.metadata:  # docs/extensions/gyro-delay.md
        hello["gyro_delay_s"] = recording.gyro_delay_s
    if recording.points:  # docs/extensions/points.md
        frame = recording.points_frame
        assert frame is not None
        hello["points"] = {"names": list(recording.points), "frame": frame.kind,
                           **({"thorax_yaw_deg": frame.thorax_yaw_deg}
                              if frame.thorax_yaw_deg is not None else {}),
                           **({"shoulder_m": list(frame.shoulder_m)}
                              if frame.shoulder_m is not None else {})}
    return hello


def _nine_axis(recording: Recording) -> bool:
    kinds = {s.nine_axis for s in recording.sensors.values()}
    if len(kinds) > 1:
        raise InvalidArgument("the kit's sensors must be all 9-axis or all 6-axis "
                              "(hello has one nine_axis flag)")
    return kinds != {False}


class MessagePlan:
    """Every ``samples`` and ``mark`` message of a recording, numbered by ``seq`` from 0.

    Each sensor's rows are cut into messages of ``rows_per_message`` rows (the last may
    be shorter); sensors interleave by send time, i.e. the time [s] of a message's last
    row; a mark is sent at its ``t``. Ties keep samples before marks, then sensors in
    the recording's order.

    times: send time of each message [s, recording clock], shape (len,), non-decreasing.
    """

    def __init__(self, recording: Recording, rows_per_message: int = 10):
        if not 1 <= rows_per_message <= MAX_ROWS_PER_MESSAGE:
            raise InvalidArgument(f"rows_per_message must be 1 to {MAX_ROWS_PER_MESSAGE}, "
                                  f"got {rows_per_message}")
        self.recording = recording
        self.rows_per_message = rows_per_message
        self.sensors: tuple[str, ...] = tuple(recording.sensors)
        self.nine_axis = _nine_axis(recording)
        self.marks = recording_marks(recording)
        # per sensor, the rows' numbers as one (N, 10) or (N, 7) float64 table
        self._tables: list[np.ndarray] = []
        times, kinds, index, starts, stops = [], [], [], [], []
        for k, (name, stream) in enumerate(recording.sensors.items()):
            parts = [stream.t[:, None], stream.acc, stream.gyr]
            if stream.mag is not None:
                parts.append(stream.mag)
            table = np.hstack(parts)
            bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
            if len(bad):
                raise InvalidArgument(f"sensor {name} row {bad[0]} holds a non-finite number; "
                                      "JSON cannot carry it")
            self._tables.append(table)
            start = np.arange(0, len(table), rows_per_message)
            stop = np.minimum(start + rows_per_message, len(table))
            times.append(stream.t[stop - 1] if len(table) else np.empty(0))
            kinds.append(np.full(len(start), _SAMPLES))
            index.append(np.full(len(start), k))
            starts.append(start)
            stops.append(stop)
        self.total_rows = int(sum(len(t) for t in self._tables))  # IMU rows
        # wrist points (docs/extensions/points.md): sent like samples, as ``points``
        self.points: tuple[str, ...] = tuple(recording.points)
        for j, points in enumerate(recording.points.values()):
            table = np.column_stack([points.t, points.p])
            self._tables.append(table)
            start = np.arange(0, len(table), rows_per_message)
            stop = np.minimum(start + rows_per_message, len(table))
            times.append(points.t[stop - 1])
            kinds.append(np.full(len(start), _SAMPLES))
            index.append(np.full(len(start), len(self.sensors) + j))
            starts.append(start)
            stops.append(stop)
        n_marks = len(self.marks)
        times.append(np.array([m.t for m in self.marks], dtype=np.float64))
        kinds.append(np.full(n_marks, _MARK))
        index.append(np.arange(n_marks))
        starts.append(np.zeros(n_marks, dtype=np.int64))
        stops.append(np.zeros(n_marks, dtype=np.int64))
        times_all = np.concatenate(times).astype(np.float64)
        kinds_all = np.concatenate(kinds).astype(np.int64)
        index_all = np.concatenate(index).astype(np.int64)
        order = np.lexsort((index_all, kinds_all, times_all))
        self.times: np.ndarray = times_all[order]
        self._kind = kinds_all[order]
        self._index = index_all[order]
        self._start = np.concatenate(starts).astype(np.int64)[order]
        self._stop = np.concatenate(stops).astype(np.int64)[order]

    def __len__(self) -> int:
        return len(self.times)

    @property
    def start_time(self) -> float:
        """Where the kit's clock starts [s, recording clock]: the first sample's or
        mark's time, whichever is earlier; 0 for an empty plan."""
        firsts = [float(s.t[0]) for s in self.recording.sensors.values() if len(s)]
        firsts += [m.t for m in self.marks[:1]]
        return min(firsts, default=0.0)

    def rows(self, seq: int) -> int:
        """The number of sample rows message ``seq`` carries (0 for a mark or points)."""
        if self._kind[seq] == _MARK or self._index[seq] >= len(self.sensors):
            return 0
        return int(self._stop[seq] - self._start[seq])

    def message(self, seq: int, wire_seq: int | None = None) -> dict[str, Any]:
        """Message ``seq`` as a dict ready for :func:`encode`, numbered ``wire_seq`` on
        the wire (default ``seq``; a session after the first starts again from 0)."""
        number = seq if wire_seq is None else wire_seq
        if self._kind[seq] == _MARK:
            mark = self.marks[self._index[seq]]
            return {"type": "mark", "seq": number, "t": mark.t, "label": mark.label}
        k = int(self._index[seq])
        block = self._tables[k][self._start[seq]:self._stop[seq]]
        if k >= len(self.sensors):
            return {"type": "points", "seq": number, "point": self.points[k - len(self.sensors)],
                    "rows": block.tolist()}
        if block.shape[1] == 10:
            rows = block.tolist()
        else:  # 6-axis: the magnetometer columns are null
            full = np.empty((len(block), 10), dtype=object)
            full[:, :7] = block
            full[:, 7:] = None
            rows = full.tolist()
        return {"type": "samples", "seq": number, "sensor": self.sensors[k], "rows": rows}

    def encode(self, seq: int, wire_seq: int | None = None) -> str:
        """Message ``seq`` as JSON text (numbered ``wire_seq``, default ``seq``)."""
        return encode(self.message(seq, wire_seq))
