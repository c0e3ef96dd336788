"""How fast the server reads one kit's messages (``ARMTRACK_KIT_MESSAGES_PER_S``,
``ARMTRACK_KIT_ROWS_PER_S``), all its streams together: back-pressure, never a refusal.

A kit past its budget is not read for a while: its socket's messages wait in the kernel,
TCP pushes back on the kit, which sends them later; nothing is refused, nothing acked is
lost. Without it one kit token's four streams of valid messages took the event loop
whole (``tests/test_security_ingest_flood.py``). A connection handling messages that one
read brought in at once also lets the loop serve others every ``SLICE_S``. A kit flooding
small messages far past its budget fills the kernel's buffers with tens of seconds of
them; its answers to the server's keepalive pings wait behind them, and after 20 s the
server closes it (1011, keepalive ping timeout): a kit within its budget never meets it."""

from __future__ import annotations

import time

#: Seconds of its rates a kit may send at once after a pause (the buckets' size) [s].
BURST_S = 1.0
#: Least pause worth a timer [s]: a smaller debt is carried to the next message.
PAUSE_MIN_S = 0.005
#: Longest a connection handles messages back to back before the loop serves others [s].
SLICE_S = 0.005


class KitBudget:
    """Two token buckets, messages and sample rows, refilled at ``messages_per_s`` and
    ``rows_per_s`` [1/s], each holding up to ``BURST_S`` of its rate. Spending may take
    them below zero (a message is read whole); ``wait_s`` is how long until both are
    back to zero."""

    def __init__(self, messages_per_s: float, rows_per_s: float,
                 clock=time.monotonic):
        self.messages_per_s = float(messages_per_s)
        self.rows_per_s = float(rows_per_s)
        self._clock = clock
        self._at = clock()
        self._messages = self.messages_per_s * BURST_S
        self._rows = self.rows_per_s * BURST_S

    def _refill(self) -> None:
        now = self._clock()
        elapsed, self._at = now - self._at, now
        self._messages = min(self.messages_per_s * BURST_S,
                             self._messages + elapsed * self.messages_per_s)
        self._rows = min(self.rows_per_s * BURST_S, self._rows + elapsed * self.rows_per_s)

    def spend(self, messages: int = 0, rows: int = 0) -> None:
        """Count ``messages`` messages and ``rows`` sample rows read."""
        self._refill()
        self._messages -= messages
        self._rows -= rows

    def wait_s(self) -> float:
        """Seconds [s] before the kit's next message may be read (0: now)."""
        self._refill()
        return max(0.0, -self._messages / self.messages_per_s, -self._rows / self.rows_per_s)

    def full(self) -> bool:
        """Nothing spent that is not refilled: a new budget would be the same."""
        self._refill()
        return (self._messages >= self.messages_per_s * BURST_S
                and self._rows >= self.rows_per_s * BURST_S)
