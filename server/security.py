"""The server's protections around the routes (README "Security"): security headers on
every answer (a Content-Security-Policy on pages), request body size limits (413), the
sign-in rate limit (429 with ``Retry-After``), and the settings ``armtrack serve`` refuses
to start with outside demo mode."""

from __future__ import annotations

import base64
import hashlib
import ipaddress
import json
import math
import re
import time
from collections import deque
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


class _TooLarge(BaseException):
    """Raised from ``receive`` past the limit; a BaseException so that no body parser
    turns it into a 400 on its way out."""


class BodyLimit:
    """Pure ASGI: a request body over the limit is refused with 413, by its
    ``Content-Length`` before it is read, or as soon as a chunked body passes it."""

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

        async def limited() -> dict:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _TooLarge
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


async def _refuse(send: Any, status: int, detail: str,
                  headers: list[tuple[bytes, bytes]] = ()) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class LoginLimiter:
    """Failed sign-ins per user name and per client address in a sliding window: at
    ``max_failures`` the key is locked until its oldest failure leaves the window (every
    attempt refused, a right password too). A success clears the user name's failures."""

    def __init__(self, max_failures: int, window_s: float):
        self.max_failures = max_failures
        self.window_s = window_s
        self._failures: dict[str, deque[float]] = {}

    def _recent(self, key: str, now: float) -> deque[float]:
        times = self._failures.get(key)
        if times is None:
            return deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        if not times:
            del self._failures[key]
        return times

    def retry_after(self, keys: list[str]) -> int | None:
        """Seconds until an attempt is allowed again, or None when it is now."""
        now = time.monotonic()
        waits = [times[-self.max_failures] + self.window_s - now
                 for key in keys if len(times := self._recent(key, now)) >= self.max_failures]
        return max(1, math.ceil(max(waits))) if waits else None

    def failed(self, keys: list[str]) -> None:
        now = time.monotonic()
        if len(self._failures) > 100_000:  # bound the memory an attacker can make us use
            for key in list(self._failures):
                self._recent(key, now)
        for key in keys:
            self._failures.setdefault(key, deque()).append(now)

    def succeeded(self, key: str) -> None:
        self._failures.pop(key, None)


def login_keys(username: str, client: str | None) -> list[str]:
    return [f"user:{username.strip().lower()}", f"addr:{client or '?'}"]


def _loopback(host: str) -> bool:
    if host in ("localhost", ""):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


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
    if not _loopback(settings.host) and not settings.tls_cert and not settings.behind_proxy:
        problems.append(
            f"ARMTRACK_HOST={settings.host} is reachable from other machines but "
            "the server has no TLS: set ARMTRACK_TLS_CERT and ARMTRACK_TLS_KEY, or "
            "ARMTRACK_BEHIND_PROXY=true when a reverse proxy in front terminates TLS")
    return problems
