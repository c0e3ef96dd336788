"""How many live feeds one account holds: each open ``/ws/live``, each open 3D view and each
viewer grant not yet used takes a slot of its therapist; one therapist holds at most
``ARMTRACK_MAX_LIVE_FEEDS_PER_USER`` (all their sign-ins together, in this server
instance). A feed gives its slot back when it ends; an unused grant's slot lapses with the
grant. Safe to use from any thread."""

from __future__ import annotations

import threading
import time

SETTING = "ARMTRACK_MAX_LIVE_FEEDS_PER_USER"


class Slot:
    """One feed's place; ``release`` is idempotent."""

    __slots__ = ("_book", "expires_at", "user_id")

    def __init__(self, book: FeedSlots, user_id: int, expires_at: float | None):
        self._book = book
        self.user_id = user_id
        #: ``time.monotonic()`` [s] after which the slot is free by itself (None: held)
        self.expires_at = expires_at

    def hold(self) -> None:
        """Keep the slot until ``release`` (a grant's view has opened)."""
        with self._book._lock:
            self.expires_at = None

    def release(self) -> None:
        self._book._release(self)


class FeedSlots:
    """At most ``limit`` slots per user id."""

    def __init__(self, limit: int):
        self.limit = limit
        self._held: dict[int, set[Slot]] = {}
        self._lock = threading.Lock()

    def take(self, user_id: int, expires_in_s: float | None = None) -> Slot | None:
        """A slot for ``user_id`` (lapsing after ``expires_in_s`` [s] unless held), or None
        when they hold ``limit`` already."""
        now = time.monotonic()
        with self._lock:
            held = self._held.setdefault(user_id, set())
            for slot in [s for s in held if s.expires_at is not None and s.expires_at <= now]:
                held.discard(slot)
            if len(held) >= self.limit:
                return None
            slot = Slot(self, user_id, None if expires_in_s is None else now + expires_in_s)
            held.add(slot)
            return slot

    def held(self, user_id: int) -> int:
        """Slots ``user_id`` holds now."""
        now = time.monotonic()
        with self._lock:
            return sum(1 for s in self._held.get(user_id, ())
                       if s.expires_at is None or s.expires_at > now)

    def refusal(self) -> str:
        """Why a feed over the limit is refused, naming the setting."""
        return (f"this account has {self.limit} live feeds and 3D views open already (each "
                f"live session page holds 2), the most one account may ({SETTING} = "
                f"{self.limit}): close a tab first")

    def close_reason(self) -> str:
        """The short form, for a WebSocket close (at most 123 bytes)."""
        return f"too many live feeds open: at most {self.limit} ({SETTING})"

    def _release(self, slot: Slot) -> None:
        with self._lock:
            held = self._held.get(slot.user_id)
            if held is not None:
                held.discard(slot)
                if not held:
                    del self._held[slot.user_id]
