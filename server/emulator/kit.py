"""A sensor kit played back from a recording: the device side of ``docs/spec/ingest.md``.

:class:`KitEmulator` connects to ``/ws/ingest``, says ``hello``, and sends the
recording's ``samples`` and ``mark`` messages paced by the recording's clock (``speed``
times real time), keeping every unacked message until an ``ack`` or ``error`` covers it.
A lost connection is resumed (``hello`` with ``resume`` = the stream id) with backoff,
and what the server's ``next_seq`` shows missing is sent again. When everything is
acked it says ``bye`` and closes with 1000. A message refused because its session is
full (``ARMTRACK_MAX_SESSION_SAMPLES``) is not lost: once the rest of that session is
acked the kit says ``bye`` and goes on in a new session (``hello`` with ``resume`` null,
naming the full one in ``carries_on``: carried-on/1),
starting with what was refused, numbered from 0 again.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import inspect
import json
import math
import random
import re
import time
from collections.abc import Awaitable, Callable, Iterable
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

from armtrack.estimator.errors import InvalidArgument
from armtrack.estimator.recording import Recording
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus, InvalidURI
from websockets.uri import parse_uri

from ..ingest.carried_on import EXTENSION as CARRIED_ON
from ..ingest.protocol import SESSION_FULL, SHORT_CLOSE_REASON, SHORT_CLOSE_REASONS
from .messages import MessagePlan, encode, hello_message
from .outbox import KitError, KitRefused, KitStats, Outbox

#: Close codes after which reconnecting cannot help, with what they mean.
FATAL_CLOSE_CODES: dict[int, str] = {
    4401: "the server refused the token",
    4400: "the server refused the protocol",
    1009: "the server refused a message as too big",
    4429: "the server refuses this kit for now",
    1008: "the server closed the connection for a policy violation",
    1003: "the server refused the data",
}

_EXPECTED = re.compile(r"expected\s+(\d+)")

#: The close code of a server that refuses the kit for now, in answer to its ``hello``
#: (too many new sessions this hour, too many streams open): the kit waits and tries again
#: (``busy_retry_s``). The same code after ``ready`` means the server refused too many of
#: the kit's messages (its own bad data): fatal, no retry.
CLOSE_BUSY = 4429

AckCallback = Callable[[int, KitStats], Awaitable[None] | None]


class _Resync(Exception):
    """The server refused a message as out of order: reconnect and resend from its
    ``next_seq``."""


class _Dropped(Exception):
    """The connection was dropped on purpose (``drop_after_seqs``)."""


class _NextSession(Exception):
    """The session is full and closed (``bye``): go on in a new one."""


#: Close reasons that say "the error message sent just before this close says why"
#: (``server/ingest/protocol.py``): the kit reports that error instead.
_POINTING_REASONS = frozenset({SHORT_CLOSE_REASON, *SHORT_CLOSE_REASONS.values()})

class KitEmulator:
    """Streams one recording to the server as a sensor kit would.

    recording: what to play. url: ``ws://host:port/ws/ingest`` (or ``wss://``).
    token: the device token, sent as ``Authorization: Bearer`` (or as ``?token=`` with
    ``token_in_query``). device: the ``hello`` device name. rows_per_message: rows per
    ``samples`` message, 1 to 1000. speed: playback speed (1 real time, 10 ten times
    faster, 0 or ``inf`` as fast as possible). rate_hz: the ``hello`` rate [Hz]
    (default the recording's). on_ack: called as ``on_ack(seq, stats)`` after each ``ack``
    is handled (may be a coroutine function; the receiver waits for it).
    drop_after_seqs: seqs right after whose first send the connection is cut (transport
    aborted, no close frame), once each, to exercise resume. max_retries: consecutive
    failed connections (none making progress) before giving up. backoff_s: first and
    longest wait between reconnects [s] (doubling, with jitter). ack_timeout_s: how long
    [s] unacked messages may wait for any ``ack`` before the connection counts as dead.
    open_timeout_s: time [s] for the handshake and for ``ready``.
    busy_retry_s: how long [s] it keeps trying while the server refuses the kit for now
    (close 4429), waiting ``busy_backoff_s`` (first, longest; doubling, as the phone kit:
    0.5 to 5 s) between tries; then it gives up (:class:`KitRefused`). on_busy: called as
    ``on_busy(reason, wait_s, left_s)`` before each such wait.
    hello_extra: fields added to ``hello`` (extensions, e.g. ``{"extensions":
    ["programs/1"], "program": "Shoulder"}``); the last ``ready`` is kept in
    :attr:`ready`. ratings: ``effort_pain`` messages (``docs/extensions/effort-pain.md``)
    sent once every sample and mark is acked, each again after a reconnect until its
    ``effort_pain_stored`` came; ``bye`` waits for them.

    ``await run()`` streams everything and returns :attr:`stats`; it raises
    :class:`KitRefused` when the server refuses the kit for good and :class:`KitError`
    when it breaks the protocol or cannot be reached.
    """

    def __init__(self, recording: Recording, url: str, token: str, *,
                 device: str = "armtrack-emulator", rows_per_message: int = 10,
                 speed: float = 1.0, rate_hz: float | None = None,
                 token_in_query: bool = False, on_ack: AckCallback | None = None,
                 drop_after_seqs: Iterable[int] = (), max_retries: int = 8,
                 backoff_s: tuple[float, float] = (0.2, 5.0), ack_timeout_s: float = 15.0,
                 open_timeout_s: float = 10.0, hello_extra: dict[str, Any] | None = None,
                 ratings: Iterable[dict[str, Any]] = (), busy_retry_s: float = 60.0,
                 busy_backoff_s: tuple[float, float] = (0.5, 5.0),
                 on_busy: Callable[[str, float, float], None] | None = None):
        if not (speed >= 0):
            raise InvalidArgument(f"speed must be >= 0 (0 or inf: as fast as possible), "
                                  f"got {speed}")
        try:
            parse_uri(url)
        except InvalidURI as exc:
            raise InvalidArgument(f"not a ws:// or wss:// URL: {url!r} ({exc})") from None
        self.recording = recording
        self.plan = MessagePlan(recording, rows_per_message)
        self.hello = {**hello_message(recording, device, None, rate_hz),
                      **(hello_extra or {})}
        #: the last ``ready`` the server sent
        self.ready: dict[str, Any] | None = None
        self.ratings = {r["id"]: {**r, "type": "effort_pain"} for r in ratings}
        #: ids of the ratings the server said it stored
        self.ratings_stored: set[str] = set()
        self._ratings_done = asyncio.Event()
        if not self.ratings:
            self._ratings_done.set()
        self.url = url
        self.token = token
        self.token_in_query = token_in_query
        self.speed = speed
        self.on_ack = on_ack
        self.drop_after_seqs = set(drop_after_seqs)
        self.max_retries = max_retries
        self.backoff_s = backoff_s
        self.ack_timeout_s = ack_timeout_s
        self.open_timeout_s = open_timeout_s
        if not (busy_retry_s >= 0):
            raise InvalidArgument(f"busy_retry_s must be >= 0 [s], got {busy_retry_s}")
        self.busy_retry_s = busy_retry_s
        self.busy_backoff_s = busy_backoff_s
        self.on_busy = on_busy
        self.stats = KitStats(total=len(self.plan))
        self.outbox = Outbox(self.stats)
        #: the plan's message of each seq sent in this session (wire seq → plan seq)
        self._wire: list[int] = []
        self._plan_next = 0  # the plan's first message never sent
        #: plan seqs refused because their session was full, to send first in the next
        self._carry: list[int] = []
        self._full = False  # this session is full: send nothing new, bye once acked
        #: the full session a new one carries on (carried-on/1, docs/extensions/carried-on.md)
        self._carries_on: int | None = None
        self._t0 = self.plan.start_time  # the recording-clock time [s] of _wall0
        self._wall0: float | None = None  # monotonic time [s] of the first ready
        self._all_acked = asyncio.Event()
        self._server_bye = False

    # the public face

    @property
    def stream(self) -> str | None:
        """The stream id from the first ``ready``, or None before it."""
        return self.stats.stream

    @property
    def done(self) -> bool:
        """True when every message has been sent and acked or refused."""
        return self._next_message() is None and not self._full and not self.outbox.pending

    def _next_message(self) -> int | None:
        """The plan seq to send next in this session: what a full session refused first,
        then the plan's next; None when all is sent."""
        if self._carry:
            return self._carry[0]
        return self._plan_next if self._plan_next < len(self.plan) else None

    def due(self, seq: int) -> float:
        """The monotonic time [s] when message ``seq`` is due (``-inf`` unpaced)."""
        if self._wall0 is None or self.speed == 0 or math.isinf(self.speed):
            return -math.inf
        return self._wall0 + (float(self.plan.times[seq]) - self._t0) / self.speed

    async def run(self) -> KitStats:
        """Stream the whole recording, reconnecting as needed; returns :attr:`stats`.
        Call it once per emulator."""
        failures = 0  # connections in a row that ended without any ack or refusal
        busy_since: float | None = None  # the first of the refusals "for now" in a row
        busy_tries = 0
        while True:
            handled = self.stats.acked + self.stats.refused
            connections = self.stats.connections
            try:
                await self._connection()
                return self.stats
            except _Dropped:
                continue  # reconnect at once
            except _NextSession:
                self._new_session()
                failures, busy_since, busy_tries = 0, None, 0
                continue
            except _Resync:
                failures = 0 if self.stats.acked + self.stats.refused > handled else failures + 1
                if failures > self.max_retries:
                    raise KitError("the server keeps refusing messages as out of order: "
                                   f"{self.stats.errors[-1]['reason']}") from None
            except (ConnectionClosed, OSError, TimeoutError, InvalidHandshake) as exc:
                if self.stats.connections > connections:  # let in meanwhile: a new spell
                    busy_since, busy_tries = None, 0
                if isinstance(exc, ConnectionClosed) and exc.rcvd is not None \
                        and exc.rcvd.code == CLOSE_BUSY:
                    if self.stats.connections > connections:  # after ready: its bad data
                        last = self.stats.errors[-1]["reason"] if self.stats.errors else ""
                        raise KitRefused(
                            f"the server closed the stream for too many refused messages: "
                            f"{exc.rcvd.reason or 'close code 4429'}"
                            + (f" (the last refused: {last})" if last else "")
                            + " (close code 4429)", CLOSE_BUSY, exc.rcvd.reason) from exc
                    now = time.monotonic()
                    busy_since = now if busy_since is None else busy_since
                    left = self.busy_retry_s - (now - busy_since)
                    if left <= 0:
                        try:
                            self._raise_if_fatal(exc)  # KitRefused, with the server's words
                        except KitRefused as refused:
                            refused.busy = True
                            raise
                    busy_tries += 1
                    first, longest = self.busy_backoff_s
                    delay = min(longest, first * 2 ** (busy_tries - 1), left)
                    if self.on_busy is not None:
                        self.on_busy(self._refusal_words(exc), delay, left)
                    await asyncio.sleep(delay)
                    continue
                self._raise_if_fatal(exc)
                failures = 0 if self.stats.acked + self.stats.refused > handled else failures + 1
                if failures > self.max_retries:
                    raise KitError(f"gave up after {failures} failed connections to "
                                   f"{self.url}: {_describe(exc)}") from exc
                first, longest = self.backoff_s
                delay = min(longest, first * 2 ** max(failures - 1, 0))
                await asyncio.sleep(delay * random.uniform(0.5, 1.0))

    def _new_session(self) -> None:
        """After a full session's ``bye``: the next ``hello`` starts a new session (no
        resume), its seqs from 0, what was refused first."""
        self.outbox = Outbox(self.stats)
        self._wire = []
        self._full = False
        self._carries_on = self.stats.session  # the new session names it in hello
        self.stats.stream = None
        self._all_acked.clear()

    # one connection

    def _connect_url(self) -> str:
        if not self.token_in_query:
            return self.url
        parts = urlsplit(self.url)
        query = [*parse_qsl(parts.query), ("token", self.token)]
        return urlunsplit(parts._replace(query=urlencode(query)))

    async def _connection(self) -> None:
        headers = None if self.token_in_query else {"Authorization": f"Bearer {self.token}"}
        async with connect(self._connect_url(), additional_headers=headers,
                           open_timeout=self.open_timeout_s, max_size=2**20) as ws:
            resend = await self._handshake(ws)
            receiver = asyncio.create_task(self._receive(ws))
            sender = asyncio.create_task(self._send(ws, resend))
            try:
                done, _ = await asyncio.wait({receiver, sender},
                                             return_when=asyncio.FIRST_COMPLETED)
                if sender in done:
                    sender.result()  # raises what the sender met
                    return
                receiver.result()  # raises; a receiver never ends quietly before bye
                raise KitError("the server stopped without closing")
            finally:
                for task in (receiver, sender):
                    task.cancel()
                    with contextlib.suppress(asyncio.CancelledError, Exception):
                        await task

    async def _handshake(self, ws: ClientConnection) -> list[int]:
        """Say ``hello`` and wait for ``ready``; returns the seqs to send again."""
        hello = dict(self.hello, resume=self.stats.stream)
        if self.stats.stream is None and self._carries_on is not None:
            asked = hello.get("extensions", [])
            hello["extensions"] = asked if CARRIED_ON in asked else [*asked, CARRIED_ON]
            hello["carries_on"] = self._carries_on
        await self._send_text(ws, encode(hello))
        async with asyncio.timeout(self.open_timeout_s):
            while True:
                message = _parse(await ws.recv())
                kind = message.get("type")
                if kind == "ready":
                    break
                if kind == "error":  # the close that follows says whether it is fatal
                    self.outbox.refuse(message.get("seq"), str(message.get("reason", "")))
                    continue
                raise KitError(f"expected ready, got {message!r}")
        self.ready = message
        stream, next_seq = message.get("stream"), message.get("next_seq")
        if not isinstance(next_seq, int) or isinstance(next_seq, bool) or stream is None:
            raise KitError(f"ready must carry a stream id and an integer next_seq: {message!r}")
        if self.stats.stream is None:
            if next_seq != 0:
                raise KitError(f"a new stream must start at next_seq 0, got {next_seq}")
            self.stats.stream, self.stats.session = stream, message.get("session")
            self.stats.sessions.append(self.stats.session)
        elif stream != self.stats.stream:
            raise KitError(f"asked to resume stream {self.stats.stream!r}, "
                           f"the server opened {stream!r}")
        self.stats.connections += 1
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now
            self.stats.started = now
        resend = self.outbox.resume(next_seq)
        self._check_done()
        return resend

    async def _send(self, ws: ClientConnection, resend: list[int]) -> None:
        """Send again what is unacked, then the plan's new messages on time; when all is
        acked, ``bye`` and close 1000."""
        outbox = self.outbox
        for seq in resend:
            if seq in outbox.pending:  # an ack may have come meanwhile
                await self._send_text(ws, outbox.pending[seq].text)
                outbox.resent(seq, time.monotonic())
                await asyncio.sleep(0)
        while not self._full and (seq := self._next_message()) is not None:
            wait = self.due(seq) - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
                if self._full:  # refused meanwhile: nothing new goes to a full session
                    break
            text = self.plan.encode(seq, outbox.next_seq)
            await self._send_text(ws, text)
            if self._carry:
                self._carry.pop(0)
            else:
                self._plan_next += 1
            self._wire.append(seq)
            outbox.sent(outbox.next_seq, text, self.plan.rows(seq), time.monotonic())
            if seq in self.drop_after_seqs:
                self.drop_after_seqs.discard(seq)
                self.stats.drops += 1
                ws.transport.abort()
                raise _Dropped
            await asyncio.sleep(0)  # let acks in when sending unpaced
        self._check_done()
        await self._all_acked.wait()
        if self._full:  # the rest of the full session is stored: close it, go on
            await self._send_text(ws, encode({"type": "bye"}))
            await ws.close(1000)
            raise _NextSession
        for rid, rating in self.ratings.items():
            if rid not in self.ratings_stored:
                await self._send_text(ws, encode(rating))
        await self._ratings_done.wait()
        await self._send_text(ws, encode({"type": "bye"}))
        self.stats.finished = time.monotonic()
        await ws.close(1000)

    async def _receive(self, ws: ClientConnection) -> None:
        """Handle ``ack`` and ``error`` until the connection closes; a connection with
        unacked messages and no ``ack`` for ``ack_timeout_s`` counts as dead."""
        outbox = self.outbox
        heard = time.monotonic()  # the last ack, or the connection's start
        while True:
            try:
                async with asyncio.timeout(1.0):
                    raw = await ws.recv()
            except TimeoutError:
                if outbox.pending:
                    oldest = next(iter(outbox.pending.values())).sent_at
                    if time.monotonic() - max(heard, oldest) > self.ack_timeout_s:
                        ws.transport.abort()
                        raise TimeoutError(f"no ack for {self.ack_timeout_s} s") from None
                continue
            message = _parse(raw)
            kind = message.get("type")
            if kind == "ack":
                seq = message.get("seq")
                if not isinstance(seq, int) or isinstance(seq, bool):
                    raise KitError(f"ack without an integer seq: {message!r}")
                heard = time.monotonic()
                outbox.ack(seq, heard)
                self._check_done()
                if self.on_ack is not None:
                    result = self.on_ack(seq, self.stats)
                    if inspect.isawaitable(result):
                        await result
            elif kind == "error":
                seq, reason = message.get("seq"), str(message.get("reason", ""))
                expected = _EXPECTED.search(reason)
                if expected and isinstance(seq, int) and seq in outbox.pending:
                    # out of order: the message must be sent again, not dropped
                    outbox.stats.errors.append({"seq": seq, "reason": reason})
                    ws.transport.abort()  # a lost connection, not an ended session
                    raise _Resync
                if reason.startswith("effort_pain:"):
                    raise KitError(f"the server refused a rating: {reason}")
                if SESSION_FULL in reason and isinstance(seq, int) and seq in outbox.pending:
                    # the session is full: the message goes again, in the next session
                    outbox.take_back(seq)
                    bisect.insort(self._carry, self._wire[seq])
                    if not self._full:
                        self._full = True
                        self.stats.session_full.append(reason)
                    self._check_done()
                    continue
                outbox.refuse(seq if isinstance(seq, int) else None, reason)
                self._check_done()
            elif kind == "effort_pain_stored":
                self.ratings_stored.add(str(message.get("id")))
                if self.ratings_stored >= set(self.ratings):
                    self._ratings_done.set()
            elif kind == "bye":
                self._server_bye = True
            # anything else (a future message type) is ignored

    # helpers

    async def _send_text(self, ws: ClientConnection, text: str) -> None:
        await ws.send(text)

    def _check_done(self) -> None:
        """Wakes the sender once this session's messages are all acked or refused: all of
        the plan, or (a full session) all it can hold."""
        if not self.outbox.pending and (self._full or self._next_message() is None):
            self._all_acked.set()

    def _raise_if_fatal(self, exc: BaseException) -> None:
        if isinstance(exc, InvalidStatus):
            status = exc.response.status_code
            if status in (401, 403):
                raise KitRefused(f"the server refused the token (HTTP {status})",
                                 status) from exc
            if 400 <= status < 500:
                raise KitRefused(f"the server refused the connection (HTTP {status})",
                                 status) from exc
            return
        if not isinstance(exc, ConnectionClosed) or exc.rcvd is None:
            return
        code, reason = exc.rcvd.code, exc.rcvd.reason
        detail = self._refusal_words(exc)
        if code in FATAL_CLOSE_CODES:
            message = FATAL_CLOSE_CODES[code] + (f": {detail}" if detail else "")
            raise KitRefused(f"{message} (close code {code})", code, reason) from exc
        if code == 1000 and self._server_bye:
            raise KitRefused("the server ended the session (bye) before everything was "
                             "acked", code, reason) from exc


    def _refusal_words(self, exc: ConnectionClosed) -> str:
        """The server's words for a close: the ``error`` just before it (whole), else the
        close reason (at most 123 bytes). A reason that only points at that error (the
        server's short sentence when the error is longer than a close frame holds) gives
        the error."""
        reason = exc.rcvd.reason if exc.rcvd is not None else ""
        last = self.stats.errors[-1]["reason"] if self.stats.errors else ""
        pointer = reason in _POINTING_REASONS
        if last and (not reason or pointer or last.startswith(reason[:40])):
            return last
        return reason or last


def _parse(raw: str | bytes) -> dict[str, Any]:
    try:
        message = json.loads(raw)
    except ValueError:
        raise KitError(f"the server sent something other than JSON: {raw[:80]!r}") from None
    if not isinstance(message, dict):
        raise KitError(f"the server sent a non-object message: {message!r}")
    return message


def _describe(exc: BaseException) -> str:
    if isinstance(exc, ConnectionClosed) and exc.rcvd is not None:
        return f"closed with code {exc.rcvd.code} {exc.rcvd.reason!r}".rstrip()
    return str(exc) or type(exc).__name__
