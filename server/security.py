"""The server's protections around the routes (README "Security"): security headers on
every answer (a Content-Security-Policy on pages), request body size limits (413), the
sign-in rate limit (429 with ``Retry-After``), and the settings ``armtrack serve`` refuses
to start with outside demo mode."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import ipaddress
import json
import logging
import math
import re
import time
from collections import OrderedDict, deque
from functools import cache
from pathlib import Path
from typing import Any

from .settings import Settings

#: Where the dashboard's pages live (their inline scripts are allowed by hash).
PAGES = Path(__file__).resolve().parents[1] / "web" / "pages" / "static"
#: Routes that take a recording upload (``ARMTRACK_MAX_UPLOAD_BYTES``).
UPLOAD_PATHS = ("/api/recordings", "/api/recordings/inspect")

BASE_HEADERS = ((b"x-content-type-options", b"nosniff"),
                (b"referrer-policy", b"no-referrer"),
                (b"x-frame-options", b"SAMEORIGIN"))

#: Any other HTML under ``/viewer/`` (viser's page sets its own, ``web.viewer.page``):
#: nothing runs, nothing loads.
VIEWER_CSP = ("default-src 'none'; frame-ancestors 'self'; object-src 'none'; "
              "base-uri 'none'; form-action 'none'")

_INLINE_SCRIPT = re.compile(rb"<script(?![^>]*\bsrc=)[^>]*>(.*?)</script>", re.S)


@cache
def _inline_script_hashes(stamp: tuple) -> str:
    hashes = []
    for path in sorted(PAGES.glob("*.html")):
        for body in _INLINE_SCRIPT.findall(path.read_bytes()):
            digest = base64.b64encode(hashlib.sha256(body).digest()).decode()
            hashes.append(f"'sha256-{digest}'")
    return " ".join(sorted(set(hashes)))


def page_csp() -> str:
    """The dashboard pages' policy: scripts from our origin and the pages' own inline
    scripts (by hash, read again when a page changes), the 3D view in a same-origin
    iframe, no framing by others."""
    stamp = tuple((p.name, p.stat().st_mtime_ns) for p in sorted(PAGES.glob("*.html")))
    return ("default-src 'self'; script-src 'self' " + _inline_script_hashes(stamp)
            + "; style-src 'self' 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; "
            "frame-src 'self'; frame-ancestors 'self'; object-src 'none'; base-uri 'none'; "
            "form-action 'self'")


class SecurityHeaders:
    """Pure ASGI: nosniff, no-referrer and SAMEORIGIN framing on every answer; a CSP on
    HTML; ``no-store`` on API answers (patient data stays out of caches); HSTS with TLS."""

    def __init__(self, app: Any, settings: Settings):
        self.app = app
        self.hsts = bool(settings.tls_cert) or settings.behind_proxy

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope["path"]

        async def send_headers(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                present = {k.lower() for k, _ in headers}
                extra = list(BASE_HEADERS)
                content_type = next((v for k, v in headers if k.lower() == b"content-type"),
                                    b"")
                if content_type.startswith(b"text/html"):
                    csp = VIEWER_CSP if path.startswith("/viewer/") else page_csp()
                    extra.append((b"content-security-policy", csp.encode()))
                if path.startswith("/api/"):
                    extra.append((b"cache-control", b"no-store"))
                if self.hsts:
                    extra.append((b"strict-transport-security", b"max-age=31536000"))
                headers += [(k, v) for k, v in extra if k not in present]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_headers)


class UntrustedProxyNotice:
    """Pure ASGI: says in the log, once per peer (at most ``MAX_NAMED`` peers), when a
    request carries ``X-Forwarded-For`` from a peer not in ``ARMTRACK_TRUSTED_PROXIES``:
    behind such a proxy every audit entry names the proxy and all its clients share one
    sign-in limit, which nothing else shows. A trusted proxy's requests arrive with
    uvicorn's client already taken from the header (one of its addresses): no notice."""

    MAX_NAMED = 8  # a client forging the header itself cannot fill the log

    def __init__(self, app: Any, settings: Settings):
        self.app = app
        self.trusted = trusted_proxies(settings)
        self.named: set[str] = set()

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] in ("http", "websocket") and len(self.named) < self.MAX_NAMED:
            self._look(scope)
        await self.app(scope, receive, send)

    def _look(self, scope: dict) -> None:
        forwarded = next((v for k, v in scope.get("headers", ()) if k == b"x-forwarded-for"),
                         None)
        client = scope.get("client")
        if forwarded is None or not client or client[0] in self.named:
            return
        peer = client[0]
        named = {a.strip() for a in forwarded.decode("latin-1").split(",")}
        if peer in named:  # taken from the header: the peer before it was trusted
            return
        self.named.add(peer)
        setting = ",".join([*self.trusted, peer])
        logging.getLogger("armtrack.security").warning(
            "the peer %s forwards requests (X-Forwarded-For) but is not in "
            "ARMTRACK_TRUSTED_PROXIES: the audit log and the sign-in limit see %s for every "
            "client behind it. If it is your reverse proxy, set "
            "ARMTRACK_TRUSTED_PROXIES=%s (or its network); if not, that client wrote the "
            "header itself and it is ignored (docs/security.md)", peer, peer, setting)


class _TooLarge(BaseException):
    """Raised from ``receive`` past the limit; a BaseException so that no body parser
    turns it into a 400 on its way out."""


class _Stalled(BaseException):
    """Raised from ``receive`` when the next part of a body does not come in time."""


class BodyLimit:
    """Pure ASGI: a request body over the limit is refused with 413, by its
    ``Content-Length`` before it is read, or as soon as a chunked body passes it; a body
    whose next part does not come within ``ARMTRACK_BODY_TIMEOUT_S`` is cut off with 408
    (a client sending slowly holds no connection for good)."""

    def __init__(self, app: Any, settings: Settings):
        self.app = app
        self.settings = settings

    def _limit(self, path: str) -> tuple[int, str]:
        if path in UPLOAD_PATHS:
            return self.settings.max_upload_bytes, "ARMTRACK_MAX_UPLOAD_BYTES"
        return self.settings.max_body_bytes, "ARMTRACK_MAX_BODY_BYTES"

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit, name = self._limit(scope["path"])
        detail = (f"the request body is larger than {limit} bytes, the limit of this route "
                  f"({name})")
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > limit:
            await _refuse(send, 413, detail)
            return
        received = 0
        started = False
        body_done = False
        timeout = self.settings.body_timeout_s

        async def limited() -> dict:
            nonlocal received, body_done
            if body_done:  # waiting for a disconnect only: no time limit
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), timeout)
            except TimeoutError:
                raise _Stalled from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _TooLarge
                body_done = not message.get("more_body", False)
            return message

        async def tracking(message: dict) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited, tracking)
        except _TooLarge:
            if not started:
                await _refuse(send, 413, detail)
        except _Stalled:
            if not started:
                await _refuse(send, 408, f"the request body stalled: no data for {timeout:g} "
                              "s (ARMTRACK_BODY_TIMEOUT_S)")


class UploadGate:
    """Pure ASGI: an upload (``UPLOAD_PATHS``) is refused with 401 before its body is read
    unless its bearer token is a valid kit's or therapist's: nobody without one makes the
    server receive and spool up to ``ARMTRACK_MAX_UPLOAD_BYTES``. The route checks the
    token again, with everything else."""

    def __init__(self, app: Any):
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] != "POST" \
                or scope["path"] not in UPLOAD_PATHS:
            await self.app(scope, receive, send)
            return
        header = dict(scope["headers"]).get(b"authorization", b"").decode("latin-1")
        scheme, _, token = header.partition(" ")
        token = token.strip() if scheme.lower() == "bearer" else ""
        services = scope["app"].state.services
        if not token:
            detail = "sign in first: a valid bearer token is required"
        elif not await services.run_db(_uploader_known, token, services.settings.demo_mode):
            detail = "the token is unknown or has expired: sign in again"
        else:
            await self.app(scope, receive, send)
            return
        await _refuse(send, 401, detail, [(b"www-authenticate", b"Bearer")])


def _uploader_known(db: Any, token: str, demo_mode: bool) -> bool:
    """Whether ``token`` is a valid kit's or therapist's (who may upload)."""
    from .api.deps import therapist_of_token
    from .ingest.endpoint import find_device

    return find_device(db, token) is not None \
        or therapist_of_token(db, token, demo_mode) is not None


async def _refuse(send: Any, status: int, detail: str,
                  headers: list[tuple[bytes, bytes]] = ()) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class LoginLimiter:
    """Failed sign-ins slow a key down (a user name, a client address); they never lock it
    out. Within ``window_s``, a key's first ``free`` - 1 failures cost nothing; from the
    ``free``-th on, the n-th of them makes its next attempt wait 2**(n-1) s (1, 2, 4 …),
    at most ``max_delay_s``, counted from that failure: meanwhile every attempt is refused (429
    with ``Retry-After``), the right password too — else the wait would not slow a
    guesser. The owner of a name under attack thus gets in after at most ``max_delay_s``,
    while a guesser gets about one try per ``max_delay_s``. A success clears the user
    name's failures. An address that signed in to a name within ``known_s`` is not held
    by that name's wait (its own address's failures still hold it): else a guesser who
    sends a wrong password the moment each wait ends, polling meanwhile (a 429 costs no
    guess), keeps the owner out for as long as they go on (nine tries in 130 s, all 429).

    Bounded whatever it is sent: a key is a fixed-size hash of the name or address, a key
    keeps at most its last ``free`` + 32 failure times, and the table at most ``max_keys``
    keys — past that, the key whose last failure is oldest is forgotten first; the
    addresses known per name are its last ``KNOWN_PER_NAME`` that signed in, for at most
    ``max_keys`` names.

    An attempt is counted as a failure from when it is let through (``reserve``) until its
    password has been checked (``settle``): attempts sent at once would otherwise all pass
    the check before the first had failed (100 at once were 43–49 guesses, not 10). Used
    from the event loop only (no lock)."""

    #: Addresses remembered per user name as having signed in to it.
    KNOWN_PER_NAME = 8

    def __init__(self, free: int, window_s: float, max_delay_s: float = 60.0,
                 max_keys: int = 100_000, known_s: float = 30 * 24 * 3600.0):
        self.free = free
        self.window_s = window_s
        self.max_delay_s = max_delay_s
        self.max_keys = max_keys
        self.known_s = known_s
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._pending: dict[str, int] = {}  # attempts let through, not yet settled
        #: name key → address key → when that address last signed in to the name
        self._known: OrderedDict[str, OrderedDict[str, float]] = OrderedDict()

    def _recent(self, key: str, now: float) -> deque[float]:
        times = self._failures.get(key)
        if times is None:
            return deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        if not times:
            del self._failures[key]
        return times

    def _wait(self, times: deque[float], pending: int, now: float) -> float:
        beyond = len(times) + pending - self.free + 1  # the free-th failure: the first wait
        if beyond <= 0:
            return 0.0
        if pending:  # attempts under way may still fail: wait for them
            return max(1.0, times[-1] + min(2.0 ** (beyond - 1), self.max_delay_s) - now
                       if times else 1.0)
        return times[-1] + min(2.0 ** (beyond - 1), self.max_delay_s) - now

    def _holding(self, keys: list[str], now: float) -> list[str]:
        """The keys whose waits hold an attempt: all of them, but the user name's
        (``keys[0]``) for an address (``keys[1]``) that signed in to it within ``known_s``."""
        if len(keys) > 1:
            seen = self._known.get(keys[0], {}).get(keys[1])
            if seen is not None and now - seen < self.known_s:
                return keys[1:]
        return keys

    def retry_after(self, keys: list[str]) -> int | None:
        """Whole seconds until an attempt is allowed again, or None when it is now."""
        now = time.monotonic()
        wait = max((self._wait(self._recent(key, now), self._pending.get(key, 0), now)
                    for key in self._holding(keys, now)), default=0.0)
        return max(1, math.ceil(wait)) if wait > 0 else None

    def reserve(self, keys: list[str]) -> int | None:
        """Let an attempt through (None), counted as a failure until ``settle``; or the
        whole seconds it must wait (``retry_after``), nothing counted."""
        wait = self.retry_after(keys)
        if wait is None:
            for key in keys:
                self._pending[key] = self._pending.get(key, 0) + 1
        return wait

    def settle(self, keys: list[str], succeeded: bool | None) -> None:
        """The reserved attempt's outcome: a failure is counted, a success clears the user
        name's failures (``keys[0]``); None (no password was checked) counts nothing."""
        for key in keys:
            left = self._pending.get(key, 0) - 1
            if left > 0:
                self._pending[key] = left
            else:
                self._pending.pop(key, None)
        if succeeded:
            self.succeeded(keys)
        elif succeeded is not None:
            self.failed(keys)

    def failed(self, keys: list[str]) -> None:
        now = time.monotonic()
        for key in keys:
            times = self._failures.get(key)
            if times is None:
                times = self._failures[key] = deque(maxlen=self.free + 32)
            else:
                self._failures.move_to_end(key)
            times.append(now)
        while len(self._failures) > self.max_keys:
            self._failures.popitem(last=False)

    def succeeded(self, keys: list[str]) -> None:
        """The user name (``keys[0]``) signed in: its failures go, and the address
        (``keys[1]``) is known to it from now on (``known_s``)."""
        self._failures.pop(keys[0], None)
        if len(keys) < 2:
            return
        known = self._known.pop(keys[0], None) or OrderedDict()
        known.pop(keys[1], None)
        known[keys[1]] = time.monotonic()
        while len(known) > self.KNOWN_PER_NAME:
            known.popitem(last=False)
        self._known[keys[0]] = known
        while len(self._known) > self.max_keys:
            self._known.popitem(last=False)

    def __len__(self) -> int:
        return len(self._failures)


def login_keys(username: str, client: str | None) -> list[str]:
    """The limiter's keys of an attempt: its user name (case and spaces aside) and its
    client's address, each as a fixed-size hash (a 1 MB name costs 32 bytes)."""
    def digest(text: str) -> str:
        return hashlib.blake2b(text.encode("utf-8", "surrogatepass"),
                               digest_size=16).hexdigest()
    return ["user:" + digest(username.strip().lower()), "addr:" + digest(client or "?")]


def trusted_proxies(settings: Settings) -> list[str]:
    """``ARMTRACK_TRUSTED_PROXIES`` as a list of addresses and networks (empty: none)."""
    return [p.strip() for p in settings.trusted_proxies.split(",") if p.strip()]


def _loopback(host: str) -> bool:
    if host in ("localhost", ""):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


#: The PostgreSQL password docker/compose.yaml falls back to when POSTGRES_PASSWORD is
#: unset (a placeholder: every copy of armtrack has it).
COMPOSE_PLACEHOLDER_PASSWORD = "change-me"


def setting_warnings(settings: Settings) -> list[str]:
    """What ``armtrack serve`` starts with but says in its log at every start, in words
    the person who runs it can act on: settings that work and are not what a clinic
    should run (empty: nothing to say). Warnings, not refusals (``unsafe_settings``): a
    running install must be able to start while it is being mended."""
    from sqlalchemy.engine import make_url

    warnings = []
    if make_url(settings.resolved_database_url()).password == COMPOSE_PLACEHOLDER_PASSWORD:
        warnings.append(
            "WARNING: the database password is docker/compose.yaml's placeholder "
            "(POSTGRES_PASSWORD was not set): anyone who reaches the database can read "
            "and change every patient's data. A new install: set POSTGRES_PASSWORD before "
            "the first `docker compose ... up` (the postgres container takes it only when "
            "it creates its database). A running one: `docker compose -f "
            "docker/compose.yaml exec postgres psql -U armtrack -c \"ALTER USER armtrack "
            "PASSWORD 'NEW'\"`, then set POSTGRES_PASSWORD=NEW (and the password in "
            "ARMTRACK_DATABASE_URL) and `docker compose ... up -d` again "
            "(docs/operator.md#postgresql)")
    if (not _loopback(settings.host) and not settings.tls_cert
            and not (settings.public_url or "").startswith("https://")):
        warnings.append(
            f"WARNING: serving plain http on {settings.host}:{settings.port}, which other "
            "machines reach: patients' phones give the phone kit no motion sensors on an "
            "http page, and passwords would cross the network in the clear. Put a reverse "
            "proxy with a certificate in front (docs/operator.md#tls has a Caddy example) "
            "and set ARMTRACK_PUBLIC_URL to its https address (which ends this warning), "
            "or give ARMTRACK_TLS_CERT and ARMTRACK_TLS_KEY")
    return warnings


def unsafe_settings(settings: Settings, demo_account: bool) -> list[str]:
    """Why ``armtrack serve`` must not start with these settings (empty: it may).
    ``demo_account``: the database holds an enabled demo therapist (user ``demo``)."""
    problems = []
    if settings.demo_mode:
        return problems
    if demo_account:
        problems.append(
            "the database holds the demo account (therapist 'demo', made by `armtrack "
            "demo`), whose password was printed: outside demo mode (ARMTRACK_DEMO_MODE) "
            "serve another database (ARMTRACK_DATA_DIR / ARMTRACK_DATABASE_URL) or disable "
            "the account (`armtrack create-user demo --disable`)")
    if "*" in settings.cors_origin_list():
        problems.append("ARMTRACK_CORS_ORIGINS contains '*': list the origins allowed to "
                        "call the API from a browser")
    if bool(settings.tls_cert) != bool(settings.tls_key):
        problems.append("TLS needs both ARMTRACK_TLS_CERT and ARMTRACK_TLS_KEY")
    for name, path in (("ARMTRACK_TLS_CERT", settings.tls_cert),
                       ("ARMTRACK_TLS_KEY", settings.tls_key)):
        if path is not None and not Path(path).is_file():
            problems.append(f"{name}={path}: no such file")
    for proxy in trusted_proxies(settings):
        try:
            ipaddress.ip_network(proxy, strict=False)
        except ValueError:
            problems.append(f"ARMTRACK_TRUSTED_PROXIES: {proxy!r} is not an address or a "
                            "network (e.g. 10.0.0.5 or 172.18.0.0/16)")
        else:
            if proxy in ("0.0.0.0/0", "::/0"):
                problems.append("ARMTRACK_TRUSTED_PROXIES trusts every address: any "
                                "client could then choose the address it is limited by")
    if not _loopback(settings.host) and not settings.tls_cert and not settings.behind_proxy:
        problems.append(
            f"ARMTRACK_HOST={settings.host} is reachable from other machines but "
            "the server has no TLS: set ARMTRACK_TLS_CERT and ARMTRACK_TLS_KEY, or "
            "ARMTRACK_BEHIND_PROXY=true when a reverse proxy in front terminates TLS")
    return problems
