"""Turns of the exports that hold a whole session in memory, shared fairly among
therapists: a freed turn goes to the waiting therapist holding the fewest (at a tie, each
in turn), so one account's many exports, from however many sign-ins, queue behind its
own, not ahead of everyone else's (first come, first served: a therapist's export waited
behind another's whole queue)."""

from __future__ import annotations

import asyncio
from collections import deque


class FairTurns:
    """At most ``places`` held at once, each by an owner (a therapist's id). Event loop
    only."""

    def __init__(self, places: int):
        self.places = places
        self._free = places
        self._held: dict[int, int] = {}
        #: owner → its waiting turns, owners in the order they began to wait
        self._waiting: dict[int, deque[asyncio.Future]] = {}

    async def acquire(self, owner: int) -> None:
        """Wait for a turn of ``owner``'s (cancellable: nothing held then)."""
        if self._free > 0 and not self._waiting:
            self._take(owner)
            return
        turn = asyncio.get_running_loop().create_future()
        self._waiting.setdefault(owner, deque()).append(turn)
        try:
            await turn
        except asyncio.CancelledError:
            if turn.done() and not turn.cancelled():  # given just as it was cancelled
                self.release(owner)
            else:
                self._drop(owner, turn)
            raise

    def release(self, owner: int) -> None:
        """Give back one of ``owner``'s turns; the next goes to the fairest waiter."""
        if (left := self._held[owner] - 1) > 0:
            self._held[owner] = left
        else:
            del self._held[owner]
        self._free += 1
        while self._free > 0 and self._waiting:
            nxt = min(self._waiting, key=lambda o: self._held.get(o, 0))
            queue = self._waiting.pop(nxt)
            turn = queue.popleft()
            if queue:  # to the back of the owners: at a tie, each in turn
                self._waiting[nxt] = queue
            if not turn.done():
                self._take(nxt)
                turn.set_result(None)

    def _take(self, owner: int) -> None:
        self._free -= 1
        self._held[owner] = self._held.get(owner, 0) + 1

    def _drop(self, owner: int, turn: asyncio.Future) -> None:
        queue = self._waiting.get(owner)
        if queue is not None and turn in queue:
            queue.remove(turn)
            if not queue:
                del self._waiting[owner]
