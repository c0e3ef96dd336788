"""What a kit has sent and the server has not yet acknowledged (``docs/spec/ingest.md``).

The :class:`Outbox` keeps every unacked message by ``seq`` with its text; an ``ack``
drops everything up to its ``seq``, an ``error`` naming a ``seq`` drops that one (the
server refused it and used up its number), and after a reconnect the server's
``next_seq`` says what to send again. :class:`KitStats` counts it all. Times are
``time.monotonic()`` seconds.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np


class KitError(Exception):
    """The stream cannot go on: the server refused it, or broke the protocol."""


class KitRefused(KitError):
    """The server closed the connection for good: ``code`` is the WebSocket close code
    (4401 bad token, 4400 protocol, 1009 too big, 4429 too many refused messages, or
    still refused for now after the kit's ``busy_retry_s``: ``busy`` true, or the HTTP
    status when the upgrade itself was refused), ``reason`` its text."""

    def __init__(self, message: str, code: int | None = None, reason: str = "",
                 busy: bool = False):
        super().__init__(message)
        self.code = code
        self.reason = reason
        self.busy = busy


@dataclass
class KitStats:
    """Counters of one streamed recording.

    total: messages in the plan. sent: messages sent at least once (first sends).
    resent: sends after the first (after reconnects). acked: messages acknowledged
    (by an ``ack``, or by ``next_seq`` on resume). refused: messages dropped because
    of an ``error`` naming them. errors: every ``error`` received, as
    ``{"seq": int | None, "reason": str}``. rows_sent / rows_acked: sample rows in first
    sends / acked messages. bytes_sent: UTF-8 bytes of every samples/mark frame sent (resends too).
    connections: successful handshakes (``ready`` received); reconnects = connections - 1.
    drops: connections dropped on purpose (``drop_after_seqs``).
    latencies_s: per acked message, seconds from its last send to the ``ack`` covering
    it (messages acked by a resume's ``next_seq`` have none), in ack order.
    stream / session: ids from ``ready`` (the current session's). sessions: every session
    the recording went to, in order (more than one when the server's session-size cap
    made the kit start a new one; session_full: the server's words each time).
    started / finished: monotonic times [s] of the first ``ready`` and of the final
    ``bye``.
    """

    total: int = 0
    sent: int = 0
    resent: int = 0
    acked: int = 0
    refused: int = 0
    errors: list[dict] = field(default_factory=list)
    rows_sent: int = 0
    rows_acked: int = 0
    bytes_sent: int = 0
    connections: int = 0
    drops: int = 0
    latencies_s: list[float] = field(default_factory=list)
    stream: str | None = None
    session: object = None
    sessions: list = field(default_factory=list)
    session_full: list[str] = field(default_factory=list)
    started: float | None = None
    finished: float | None = None

    @property
    def reconnects(self) -> int:
        """Connections after the first of each session."""
        return max(self.connections - max(len(self.sessions), 1), 0)

    @property
    def elapsed_s(self) -> float | None:
        """Seconds from the first ``ready`` to the ``bye`` (None before both)."""
        if self.started is None or self.finished is None:
            return None
        return self.finished - self.started

    def latency_percentiles(self, q=(50, 90, 99)) -> dict[float, float]:
        """Ack latency percentiles [s] by percentile; empty without acks."""
        if not self.latencies_s:
            return {}
        values = np.percentile(np.asarray(self.latencies_s), q)
        return {p: float(v) for p, v in zip(q, values, strict=True)}


@dataclass(slots=True)
class Pending:
    """One sent, unacked message: its text, rows and last send time [s, monotonic]."""

    seq: int
    text: str
    rows: int
    sent_at: float


class Outbox:
    """The unacked messages by ``seq``, in ``seq`` order, and their bookkeeping.

    ``next_seq`` is the seq the next new message gets; messages must be added in order.
    """

    def __init__(self, stats: KitStats | None = None):
        self.stats = stats if stats is not None else KitStats()
        self.pending: OrderedDict[int, Pending] = OrderedDict()
        self.next_seq = 0
        #: the highest seq known handled (acked or refused); -1 before any
        self.handled_through = -1

    def __len__(self) -> int:
        return len(self.pending)

    def sent(self, seq: int, text: str, rows: int, now: float) -> None:
        """Record the first send of message ``seq`` (must be ``next_seq``)."""
        if seq != self.next_seq:
            raise ValueError(f"messages go out in order: expected seq {self.next_seq}, got {seq}")
        self.pending[seq] = Pending(seq, text, rows, now)
        self.next_seq += 1
        self.stats.sent += 1
        self.stats.rows_sent += rows
        self.stats.bytes_sent += len(text.encode())

    def resent(self, seq: int, now: float) -> None:
        """Record another send of pending message ``seq``."""
        entry = self.pending[seq]
        entry.sent_at = now
        self.stats.resent += 1
        self.stats.bytes_sent += len(entry.text.encode())

    def ack(self, seq: int, now: float) -> int:
        """An ``ack`` of ``seq``: drop every pending message up to it, recording its
        latency; returns how many were dropped. A seq never sent is a protocol error."""
        if seq >= self.next_seq:
            raise KitError(f"the server acked seq {seq}, but only {self.next_seq} "
                           "messages were sent")
        return self._drop_through(seq, now)

    def refuse(self, seq: int | None, reason: str) -> bool:
        """An ``error`` (``seq`` may be None): record it and drop message ``seq`` if it is
        pending; True when one was dropped."""
        self.stats.errors.append({"seq": seq, "reason": reason})
        if seq is None or seq not in self.pending:
            return False
        del self.pending[seq]
        self.stats.refused += 1
        self.handled_through = max(self.handled_through, seq)
        return True

    def take_back(self, seq: int) -> Pending:
        """Pending message ``seq`` was refused because its session is full: it leaves this
        outbox neither acked nor refused, to be sent again in a new session (counted
        there as sent, here as resent); returns it."""
        entry = self.pending.pop(seq)
        self.stats.sent -= 1
        self.stats.rows_sent -= entry.rows
        self.stats.resent += 1
        self.handled_through = max(self.handled_through, seq)
        return entry

    def resume(self, next_seq: int) -> list[int]:
        """A resumed ``ready`` says the server stored everything below ``next_seq``: drop
        those as acked (no latency) and return the pending seqs to send again, in order."""
        if next_seq > self.next_seq:
            raise KitError(f"the server's next_seq {next_seq} is beyond the "
                           f"{self.next_seq} messages sent")
        if next_seq <= self.handled_through:
            raise KitError(f"the server's next_seq {next_seq} is below seq "
                           f"{self.handled_through}, which it had already handled")
        self._drop_through(next_seq - 1, None)
        return list(self.pending)

    def _drop_through(self, seq: int, now: float | None) -> int:
        dropped = 0
        while self.pending:
            first = next(iter(self.pending))
            if first > seq:
                break
            entry = self.pending.popitem(last=False)[1]
            dropped += 1
            self.stats.acked += 1
            self.stats.rows_acked += entry.rows
            if now is not None:
                self.stats.latencies_s.append(now - entry.sent_at)
        self.handled_through = max(self.handled_through, seq)
        return dropped
