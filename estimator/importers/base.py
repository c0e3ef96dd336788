"""What every vendor reader takes and gives: source files, one sensor's converted samples
(:class:`Signal`), the options a user may set, and the error that names file and line."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import EstimatorError
from .units import DEFAULT_FIELD_UT


class ImportFailure(EstimatorError):
    """A vendor file cannot be imported; the message names the file, the line (counted
    from 1, where there is one) and the problem."""

    def __init__(self, file: str, problem: str, line: int | None = None, place: str = "line"):
        where = file if line is None else f"{file}, {place} {line}"
        super().__init__(f"{where}: {problem}")
        self.file = file
        self.line = line
        self.problem = problem
        self.place = place


class TooLarge(ImportFailure):
    """A file that holds, unpacked or decoded, more than the reader may take (``413`` on
    the API, like an upload over its limit)."""


#: Largest total size [bytes] the files of one import may unpack or decode to (a zip
#: bomb, an HDF5 file declaring huge datasets is refused, not read).
MAX_UNPACKED_BYTES = 2 << 30


@dataclass(frozen=True)
class SourceFile:
    """One file's bytes and the name the user knows it by (a path, or ``zip/member``)."""

    name: str
    data: bytes

    @property
    def basename(self) -> str:
        return self.name.replace("\\", "/").rsplit("/", 1)[-1]


@dataclass(frozen=True)
class ReadOptions:
    """Settings a user may give where a file does not say.

    field_ut: the local field [µT] one "a.u." of a normalised magnetometer stands for.
    columns: the generic reader's column map (``t=Time:ms ax=AccX:g …``).
    platform: Sensor Logger's platform when no metadata file says it (``android``,
    ``ios`` or ``standardised``).
    max_bytes: the most the files' datasets may hold unpacked [bytes] (the server passes
    its upload limit, as for a zip), checked against what a file declares before reading.
    """

    field_ut: float = DEFAULT_FIELD_UT
    columns: str | None = None
    platform: str | None = None
    max_bytes: int = MAX_UNPACKED_BYTES


@dataclass
class Signal:
    """One physical sensor's samples as found in vendor files, in the recording's units
    and the sensor's own frame (right-handed; at rest the axis pointing up reads +9.81).

    t: sample times [s] after ``epoch``; ``epoch + t`` is the time on ``clock``: ``unix``
    (s since 1970 UTC), a vendor's shared sync clock (``xsens-dot-sync``), or
    ``file:<name>`` (starts with its file; no other file shares it). Times are kept
    relative so their spacing stays exact (a float64 of seconds since 1970 is only good to
    0.24 µs, and the filters feel that jitter). lines: each sample's line in ``files[0]``
    (1-based; a sample's index in a binary file). declared_rate_hz: the rate the file
    states, if any.
    """

    format: str
    label: str
    files: tuple[str, ...]
    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray | None
    clock: str
    lines: np.ndarray
    declared_rate_hz: float | None = None
    notes: list[str] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)
    #: True where acc/mag were interpolated onto the gyroscope's times (rates differed)
    resampled: bool = False
    #: where the accelerometer's samples came from when not ``files[0]`` (signals merged
    #: from files per signal): its file and, per sample, its nearest line there
    acc_file: str | None = None
    acc_lines: np.ndarray | None = None
    #: the clock time [s] ``t`` counts from
    epoch: float = 0.0
    #: what ``lines`` count: ``line`` of a text file, or ``sample`` of a binary one
    place: str = "line"

    def __len__(self) -> int:
        return len(self.t)

    @property
    def rate_hz(self) -> float:
        """The median sample rate [Hz] (0 with fewer than two samples)."""
        if len(self.t) < 2:
            return 0.0
        dt = np.diff(self.t)
        dt = dt[dt > 0]
        return float(1.0 / np.median(dt)) if dt.size else 0.0

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0
