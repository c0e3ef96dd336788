"""Importers of vendor IMU exports into strict recordings (``docs/spec/recording.md``).

One module per format (``xsens_dot``, ``apdm``, ``shimmer``, ``metamotion``,
``sensor_logger``, ``generic``), each with ``NAME``, ``TITLE``, ``sniff(source)`` and
``read(sources, options) -> list[Signal]`` in the recording's units and the sensor's frame;
:mod:`.units` holds every unit conversion, :mod:`.checks` what every sensor must pass,
:mod:`.importer` puts sensors on one clock and builds the recording, :mod:`.poses`
proposes calibration poses. See ``docs/importing.md``.
"""

from .base import ImportFailure, ReadOptions, Signal, SourceFile, TooLarge
from .importer import (
    Assignment,
    ImportResult,
    describe,
    detect,
    formats,
    import_recording,
    read_signals,
)

__all__ = [
    "Assignment",
    "ImportFailure",
    "ImportResult",
    "ReadOptions",
    "Signal",
    "SourceFile",
    "TooLarge",
    "describe",
    "detect",
    "formats",
    "import_recording",
    "read_signals",
]
