"""How fast the server reads one kit's messages (``ARMTRACK_KIT_MESSAGES_PER_S``,
``ARMTRACK_KIT_ROWS_PER_S``), all its streams together, and all kits' together
(``ARMTRACK_INGEST_MESSAGES_PER_S``, ``ARMTRACK_INGEST_ROWS_PER_S``): back-pressure,
never a refusal.

A kit past its budget is not read for a while: its socket's messages wait in the kernel,
TCP pushes back on the kit, which sends them later; nothing is refused, nothing acked is
lost. Without it one kit token's four streams of valid messages took the event loop
whole (``tests/test_security_ingest_flood.py``). A connection handling messages that one
read brought in at once also lets the loop serve others every ``SLICE_S``. A kit flooding
small messages far past its budget fills the kernel's buffers with tens of seconds of
them; its answers to the server's keepalive pings wait behind them, and after 20 s the
server closes it (1011, keepalive ping timeout): a kit within its budget never meets it.

The kits' budget is shared in turns: each connection takes the next message's turn
(``turn_s``) before it reads it, and turns come in the order taken, so that many kits
flooding at once (each within its own budget: eight took another therapist's page from
8.5 to 2,300 ms) share the server's reading with every other stream, one message each in
turn, instead of taking the event loop whole. Its rates are the most: a loaded machine's
event loop keeps up with fewer messages (the same eight kits under the configured 8,000 a
second: another page 1.3x in one run, 418x in the next), so the kits' budget follows the
loop (``follow_loop``): while its timers fire late, kits are read more slowly. It is
shared among the kits' therapists (``SharedBudget``): a therapist's kits take turns in a
part of their own, so that one therapist's many streams never hold back another's."""

from __future__ import annotations

import asyncio
import math
import time

#: Seconds of its rates a kit may send at once after a pause (the buckets' size) [s], and
#: all kits together (theirs: a second's flood at once held the loop for half a second).
BURST_S, SHARED_BURST_S = 1.0, 0.1
#: Least pause worth a timer [s]: a smaller debt is carried to the next message.
PAUSE_MIN_S = 0.005
#: Longest a connection handles messages back to back before the loop serves others [s].
SLICE_S = 0.005
#: How often ``follow_loop`` looks at the event loop [s], and how late its timer may fire
#: before kits are read more slowly [s].
TICK_S, LATE_S = 0.02, 0.003
#: The kits' budget's share of its rates: times this each late tick, times ``FASTER``
#: each tick on time.
SLOWER, FASTER = 0.7, 1.05


class KitBudget:
    """Two token buckets, messages and sample rows, refilled at ``messages_per_s`` and
    ``rows_per_s`` [1/s], each holding up to ``burst_s`` of its rate. Spending may take
    them below zero (a message is read whole); ``wait_s`` is how long until both are
    back to zero. ``share`` (0–1] of the rates is in force (``follow_loop``)."""

    share = 1.0

    def __init__(self, messages_per_s: float, rows_per_s: float,
                 clock=time.monotonic, burst_s: float = BURST_S):
        self.messages_per_s = float(messages_per_s)
        self.rows_per_s = float(rows_per_s)
        self.burst_s = burst_s
        self._clock = clock
        self._at = clock()
        self._messages = self.messages_per_s * burst_s
        self._rows = self.rows_per_s * burst_s

    def _refill(self) -> None:
        now = self._clock()
        elapsed, self._at = now - self._at, now
        messages, rows = self.messages_per_s * self.share, self.rows_per_s * self.share
        self._messages = min(messages * self.burst_s, self._messages + elapsed * messages)
        self._rows = min(rows * self.burst_s, self._rows + elapsed * rows)

    def spend(self, messages: int = 0, rows: int = 0) -> None:
        """Count ``messages`` messages and ``rows`` sample rows read."""
        self._refill()
        self._messages -= messages
        self._rows -= rows

    def turn_s(self) -> float:
        """Take the next message's turn: seconds [s] until it comes (0: now). The message
        is counted at once, so turns taken one after another come one after another."""
        wait = self.wait_s()
        self._messages -= 1
        return wait

    def wait_s(self) -> float:
        """Seconds [s] before the kit's next message may be read (0: now)."""
        self._refill()
        return max(0.0, -self._messages / (self.messages_per_s * self.share),
                   -self._rows / (self.rows_per_s * self.share))

    def full(self) -> bool:
        """Nothing spent that is not refilled: a new budget would be the same."""
        self._refill()
        return (self._messages >= self.messages_per_s * self.burst_s
                and self._rows >= self.rows_per_s * self.burst_s)


#: How long after its last turn that had to wait a therapist's kits count as reading all
#: their part (busy) [s], and how often the busy ones are counted again [s].
BUSY_S, COUNT_EVERY_S = 1.0, 0.05


class SharedBudget:
    """All kits' budget (``ARMTRACK_INGEST_MESSAGES_PER_S``, ``_ROWS_PER_S``), shared
    among the therapists whose kits stream (the owner of a turn: its kit's therapist):
    each has a ``KitBudget`` of its own, whose part of the rates is ``share`` over the
    number of busy therapists (those whose turns had to wait within ``BUSY_S``), itself
    counted. A therapist's kits flooding therefore read at most their part while another
    therapist's stream waits on its own part only, never behind their turns; one alone,
    or beside streams that take less than theirs, reads at the whole rate less what those
    took in the last ``BUSY_S`` (``_used``): a part is at most what the others leave of
    ``share``, never under an equal part among the therapists whose kits read, so that
    together they read no faster than the whole (four therapists' kits each reading 90 %
    of it, none ever waiting, were read at 3.6 times it). Before, every
    stream took its turn in one queue, a message each whatever its size and therapist:
    a therapist's 16 streams of 1000-row messages held another's real-time kit (10 rows
    every 100 ms) to one message per round of them all (acks 0.1 → 1.9 s, falling
    behind for good). ``share`` (0–1] follows the loop (``follow_loop``)."""

    def __init__(self, messages_per_s: float, rows_per_s: float,
                 clock=time.monotonic, burst_s: float = SHARED_BURST_S):
        self.messages_per_s = float(messages_per_s)
        self.rows_per_s = float(rows_per_s)
        self.burst_s = burst_s
        self.share = 1.0
        self._clock = clock
        self._owners: dict[object, KitBudget] = {}
        self._waited: dict[object, float] = {}  # owner → its last turn that had to wait
        self._busy: set[object] = set()
        self._counted_at = -float("inf")
        #: owner → [messages, rows] read, each fading by e every ``BUSY_S`` (about their
        #: rates × ``BUSY_S``), and as fractions of the whole rates at the last count
        self._read: dict[object, list[float]] = {}
        self._read_at = clock()
        self._used: dict[object, float] = {}
        self._used_sum = 0.0

    def _budget(self, owner: object) -> KitBudget:
        """``owner``'s budget, its part of the rates set for now."""
        now = self._clock()
        if now - self._counted_at >= COUNT_EVERY_S:
            self._counted_at = now
            self._busy = {o for o, at in self._waited.items() if now - at < BUSY_S}
            for gone in [o for o in self._waited if o not in self._busy]:
                del self._waited[gone]
            for gone in [o for o, b in self._owners.items()
                         if o not in self._busy and o != owner and b.full()]:
                del self._owners[gone]  # a quiet therapist's, nothing owed: as new
            self._count_reads(now)
        budget = self._owners.get(owner)
        if budget is None:
            budget = self._owners[owner] = KitBudget(self.messages_per_s, self.rows_per_s,
                                                     self._clock, self.burst_s)
        part = self.share / (1 + len(self._busy - {owner}))
        others = self._used_sum - self._used.get(owner, 0.0)
        equal = self.share / (len(self._used) + (owner not in self._used))
        budget.share = min(part, max(equal, self.share - others))
        return budget

    def _count_reads(self, now: float) -> None:
        """Fade what each owner read by the time since the last count, and take it as
        their fractions of the whole rates (the larger of messages' and rows')."""
        fade = math.exp(-(now - self._read_at) / BUSY_S)
        self._read_at = now
        whole = (self.messages_per_s * BUSY_S, self.rows_per_s * BUSY_S)
        self._used = {}
        for owner, read in list(self._read.items()):
            read[0] *= fade
            read[1] *= fade
            used = max(read[0] / whole[0], read[1] / whole[1])
            if used < 1e-4:
                del self._read[owner]  # quiet: not counted among those reading
            else:
                self._used[owner] = used
        self._used_sum = sum(self._used.values())

    def _note(self, owner: object, messages: float, rows: float) -> None:
        read = self._read.setdefault(owner, [0.0, 0.0])
        read[0] += messages
        read[1] += rows

    def turn_s(self, owner: object = None) -> float:
        """Take the next message's turn for a kit of ``owner``: seconds [s] until it comes."""
        wait = self._budget(owner).turn_s()
        self._note(owner, 1, 0)
        if wait >= PAUSE_MIN_S:
            self._waited[owner] = self._clock()
            self._busy.add(owner)
        return wait

    def spend(self, owner: object = None, messages: int = 0, rows: int = 0) -> None:
        """Count ``messages`` messages and ``rows`` sample rows read from ``owner``'s kits."""
        self._budget(owner).spend(messages, rows)
        self._note(owner, messages, rows)


async def follow_loop(budget: KitBudget | SharedBudget, share_min: float) -> None:
    """Keep ``budget``'s share of its rates (all kits') at what the event loop keeps up
    with: each second ``TICK_S`` in a row its timer fires over ``LATE_S`` late, the share
    goes down (``SLOWER``), never below ``share_min``; each on time back up (``FASTER``).
    Runs until cancelled."""
    loop = asyncio.get_running_loop()
    late_before = False
    while True:
        at = loop.time()
        await asyncio.sleep(TICK_S)
        late = loop.time() - at - TICK_S > LATE_S
        budget.share = next_share(budget.share, late, late_before, share_min)
        late_before = late


def next_share(share: float, late: bool, late_before: bool, share_min: float) -> float:
    """The share after a tick: down when this tick and the one before were late (one
    late tick alone: the process was not scheduled), up when on time."""
    if late and late_before:
        return max(share_min, share * SLOWER)
    return share if late else min(1.0, share * FASTER)
