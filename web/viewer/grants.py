"""One-time viewer grants: what lets a browser reach the loopback viser server.

A signed-in therapist asks for a grant to view one of their patients, live, or one of
their stored sessions (``POST /api/viewer``). The grant's id is in the page address
(``/viewer/<grant>/``) and is good for ``GRANT_TTL_S`` seconds: the page may be loaded
while the grant is unused; the grant is *used* when the page's WebSocket (``/viewer/<grant>``)
claims it. Claiming mints a ticket, a second secret that only the proxy knows, which the
proxy hands to viser in its upstream URL (``?ticket=``); viser takes the ticket once to
learn whose scene to build. Neither a grant nor a ticket works twice.

Since a grant works once, a viewer whose WebSocket closed (the server restarted, the
network dropped) cannot come back: its page asks for the grant's ``state`` and, once the
grant is ``closed`` or unknown, gets a new grant.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass
from typing import Any

#: Seconds a grant stays good for its page and its WebSocket.
GRANT_TTL_S = 60.0
#: Seconds between the proxy claiming a grant and viser taking its ticket.
TICKET_TTL_S = 15.0
#: Seconds a closed viewer's grant still tells that it is closed (then it is unknown).
CLOSED_KEPT_S = 120.0

#: A grant's state: its page may still connect; its WebSocket is open; it is over.
WAITING, OPEN, CLOSED = "waiting", "open", "closed"


@dataclass
class Grant:
    """Viewing rights of one viewer: a therapist's patient, live (``session_id`` None) or
    one stored session. Times are ``time.monotonic()`` [s]."""

    id: str
    therapist_id: int
    patient_id: int
    session_id: int | None
    expires_at: float
    used: bool = False
    ticket: str | None = None
    ticket_expires_at: float = 0.0
    closed_at: float | None = None
    #: SHA-256 of the sign-in token it was issued to: the view ends with that sign-in
    token_hash: str = ""
    #: How much the page shows the view scaled down (0.2–1): its labels grow to match
    display_scale: float = 1.0
    #: its account's live-feed place (``live.slots.Slot``): lapses with the unused grant,
    #: held while its view is open, given back when the view closes
    slot: Any = None

    @property
    def live(self) -> bool:
        return self.session_id is None


class GrantBook:
    """The grants of one app; safe to use from any thread."""

    def __init__(self, ttl_s: float = GRANT_TTL_S, ticket_ttl_s: float = TICKET_TTL_S):
        self.ttl_s = ttl_s
        self.ticket_ttl_s = ticket_ttl_s
        self._grants: dict[str, Grant] = {}
        self._tickets: dict[str, Grant] = {}
        self._claimed: dict[str, Grant] = {}  # grant id → used grant, open or lately closed
        self._lock = threading.Lock()

    def issue(self, *, therapist_id: int, patient_id: int, session_id: int | None,
              token_hash: str = "", display_scale: float = 1.0, slot: Any = None) -> Grant:
        """A new grant, good for ``ttl_s``."""
        now = time.monotonic()
        grant = Grant(secrets.token_urlsafe(24), therapist_id, patient_id, session_id,
                      now + self.ttl_s, token_hash=token_hash, display_scale=display_scale,
                      slot=slot)
        with self._lock:
            self._prune(now)
            self._grants[grant.id] = grant
        return grant

    def page(self, grant_id: str) -> Grant | None:
        """The grant if its page may be served: known, unexpired and unused."""
        with self._lock:
            grant = self._grants.get(grant_id)
            if grant is None or grant.used or grant.expires_at <= time.monotonic():
                return None
            return grant

    def claim(self, grant_id: str) -> Grant | None:
        """Use the grant (once): it gets a fresh ticket for viser. None if the grant is
        unknown, expired or used."""
        now = time.monotonic()
        with self._lock:
            grant = self._grants.pop(grant_id, None)
            if grant is None or grant.used or grant.expires_at <= now:
                return None
            grant.used = True
            if grant.slot is not None:
                grant.slot.hold()
            grant.ticket = secrets.token_urlsafe(24)
            grant.ticket_expires_at = now + self.ticket_ttl_s
            self._tickets[grant.ticket] = grant
            self._claimed[grant.id] = grant
            return grant

    def close(self, grant_id: str) -> None:
        """The claimed grant's WebSocket has closed."""
        with self._lock:
            grant = self._claimed.get(grant_id)
            if grant is not None and grant.closed_at is None:
                grant.closed_at = time.monotonic()
                if grant.slot is not None:
                    grant.slot.release()

    def state(self, grant_id: str) -> tuple[Grant, str] | None:
        """The grant and its state (``WAITING``: unused and unexpired; ``OPEN``: its
        WebSocket is open; ``CLOSED``: it closed, or the grant expired unused), or None if
        the grant is unknown (never issued, or long over)."""
        now = time.monotonic()
        with self._lock:
            grant = self._claimed.get(grant_id)
            if grant is not None:
                return grant, OPEN if grant.closed_at is None else CLOSED
            grant = self._grants.get(grant_id)
            if grant is None:
                return None
            return grant, WAITING if grant.expires_at > now else CLOSED

    def take_ticket(self, ticket: str) -> Grant | None:
        """The grant of a ticket (once), or None if unknown or expired."""
        with self._lock:
            grant = self._tickets.pop(ticket, None)
            if grant is None or grant.ticket_expires_at <= time.monotonic():
                return None
            return grant

    def _prune(self, now: float) -> None:
        for key in [k for k, g in self._grants.items()
                    if g.expires_at + CLOSED_KEPT_S <= now]:
            del self._grants[key]
        for key in [k for k, g in self._claimed.items()
                    if g.closed_at is not None and g.closed_at + CLOSED_KEPT_S <= now]:
            del self._claimed[key]
        for key in [k for k, g in self._tickets.items() if g.ticket_expires_at <= now]:
            del self._tickets[key]
