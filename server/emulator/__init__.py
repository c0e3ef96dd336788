"""A sensor kit emulator: plays a recording to the server over the ingest protocol
(``docs/spec/ingest.md``), paced by the recording's clock, resuming after connection loss."""

from .kit import FATAL_CLOSE_CODES, KitEmulator
from .messages import (
    MAX_ROWS_PER_MESSAGE,
    PROTOCOL_VERSION,
    MessagePlan,
    encode,
    hello_message,
    nominal_rate,
    recording_marks,
)
from .outbox import KitError, KitRefused, KitStats, Outbox, Pending

__all__ = [
    "FATAL_CLOSE_CODES",
    "MAX_ROWS_PER_MESSAGE",
    "PROTOCOL_VERSION",
    "KitEmulator",
    "KitError",
    "KitRefused",
    "KitStats",
    "MessagePlan",
    "Outbox",
    "Pending",
    "encode",
    "hello_message",
    "nominal_rate",
    "recording_marks",
]
