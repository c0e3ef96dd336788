"""Recording files (``docs/spec/recording.md``, version 1): the data classes, a strict and
fast reader, and a writer whose files read back as the same float64 numbers.

Units: time [s], specific force [m/s^2], angular rate [rad/s], magnetic field [µT],
lengths [m], rate [Hz].
"""

from .model import FORMAT_VERSION, Mark, Pose, Recording, SensorStream
from .reader import parse_recording, read_recording
from .writer import check_recording, format_recording, write_recording, write_recording_to

__all__ = [
    "FORMAT_VERSION",
    "Mark",
    "Pose",
    "Recording",
    "SensorStream",
    "check_recording",
    "format_recording",
    "parse_recording",
    "read_recording",
    "write_recording",
    "write_recording_to",
]
