"""``armtrack serve``: the server under uvicorn, settings from the environment
(``ARMTRACK_…``) and these flags."""

from __future__ import annotations

import argparse
import logging
import re
from pathlib import Path
from urllib.parse import unquote_plus

#: ``token=…`` in a logged URL (kits that cannot set headers put their token there), and
#: the patients list's search ``q=…`` (what the therapist typed of a patient's name, sent
#: at each key: the access log wrote it whole), matched once the URL is percent-decoded
#: (``?tok%65n=`` is ``?token=`` to the server).
TOKEN_IN_URL = re.compile(r"(token=)[^&\s\"']+|([?&]q=)(?:(?!\sHTTP/)[^&\"])+",
                          re.IGNORECASE)  # a name holds spaces (+ in the URL), and ' (O'Brien)
#: The search ``q=…`` in the URL as sent, hidden before it is decoded: there a name's
#: encoded ``&`` (``%26``) does not yet end it (review19: "q=***&Augusta" was written).
SEARCH_IN_URL = re.compile(r"([?&]q=)[^&\s\"]+", re.IGNORECASE)


def redact(text: str) -> str:
    """``text`` with the value of every ``token=`` and ``q=`` replaced by ``***``, looked
    for in the text as it is and percent-decoded (where one is found, the decoded text is
    kept)."""
    text = SEARCH_IN_URL.sub(r"\1***", text)
    decoded = unquote_plus(text) if "%" in text or "+" in text else text
    if TOKEN_IN_URL.search(decoded) is None:
        return text
    return TOKEN_IN_URL.sub(lambda m: (m.group(1) or m.group(2)) + "***", decoded)

HELP = "run the server (REST API, ingest WebSocket, dashboard)"
DESCRIPTION = ("Runs armtrack under uvicorn. Settings come from the environment "
               "(ARMTRACK_DATABASE_URL, ARMTRACK_DATA_DIR, ARMTRACK_HOST, ARMTRACK_PORT, ...) "
               "and these flags; the database is migrated on start. Every setting, with the "
               "value this server would run with: armtrack serve --settings.")


class RedactTokens(logging.Filter):
    """Keeps bearer tokens given in URLs, and names searched for, out of the logs."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.args:
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        return True


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="address to listen on (ARMTRACK_HOST, default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port (ARMTRACK_PORT, default 8000)")
    add_database_arguments(parser)
    parser.add_argument("--settings", action="store_true",
                        help="print every ARMTRACK_ setting with the value this server would "
                        "run with (the environment and these flags) and what it does; start "
                        "nothing")


#: Settings whose value is a URL that may hold a password (``user:password@host``).
URL_SETTINGS = ("database_url", "broker_url")


#: A URL's query keys (any case) whose values are secrets: libpq and redis-py take a
#: password there too (``?password=…``; libpq's ``sslpassword`` unlocks the client key).
SECRET_QUERY_KEYS = ("pass", "secret", "token")


def shown_url(url: str) -> str:
    """A database (or broker) URL fit for a log or a screen: its password as ``***``,
    written ``user:password@`` or in the query (``?password=``); one that is no URL at
    all is not shown."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except ArgumentError:
        return "*** (not a URL)"
    hidden = {key: "***" for key in parsed.query
              if any(word in key.lower() for word in SECRET_QUERY_KEYS)}
    return parsed.update_query_dict(hidden).render_as_string(hide_password=True)


def settings_text(settings) -> str:
    """Every setting as ``ARMTRACK_NAME=value  # what it does`` (shell-quoted values; the
    password of a URL in ``URL_SETTINGS`` as ``***``), in the order of ``Settings``."""
    import shlex

    lines = []
    for name, field in type(settings).model_fields.items():
        value = getattr(settings, name)
        if name in URL_SETTINGS and value:
            value = shown_url(value)
        shown = "" if value is None else shlex.quote(str(value))
        lines.append(f"ARMTRACK_{name.upper()}={shown}"
                     + (f"  # {field.description}" if field.description else ""))
    return "\n".join(lines)


def add_database_arguments(parser: argparse.ArgumentParser) -> None:
    """The database's options only: for the commands that open it and listen on nothing."""
    parser.add_argument("--data-dir", type=Path,
                        help="folder for the database (ARMTRACK_DATA_DIR, default ./armtrack-data)")
    parser.add_argument("--database-url", help="SQLAlchemy URL (ARMTRACK_DATABASE_URL)")


def settings_from(args: argparse.Namespace):
    from armtrack.server.settings import Settings

    given = {k: v for k, v in (("host", getattr(args, "host", None)),
                               ("port", getattr(args, "port", None)),
                               ("data_dir", args.data_dir), ("database_url", args.database_url))
             if v is not None}
    return Settings(**given)


def demo_account_present(settings) -> bool:
    """Whether the database holds an enabled demo account (``armtrack demo``'s). The
    database is migrated first; an upgrade of an existing one is said on standard output
    (the service's log)."""
    from armtrack.server.api.deps import DEMO_USER
    from armtrack.server.db import models
    from armtrack.server.db.engine import make_engine, make_sessionmaker
    from armtrack.server.db.migrate import migrated_words, upgrade
    from sqlalchemy import select

    settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    engine = make_engine(settings.resolved_database_url())
    try:
        if words := migrated_words(*upgrade(engine)):
            print(words, flush=True)
        with make_sessionmaker(engine)() as db:
            return db.scalar(select(models.Therapist.id).where(
                models.Therapist.username == DEMO_USER,
                models.Therapist.disabled_at.is_(None))) is not None
    finally:
        engine.dispose()


def run(args: argparse.Namespace) -> int:
    import sys

    from armtrack.server.cpu_threads import one_blas_thread

    one_blas_thread()  # before numpy's first import (docs/operator.md#cpu-threads)
    import uvicorn
    from armtrack.server.api.spool import DeliberateCutNotError
    from armtrack.server.app import create_app
    from armtrack.server.security import trusted_proxies, unsafe_settings

    settings = settings_from(args)
    if args.settings:
        print(settings_text(settings))
        return 0
    problems = unsafe_settings(settings, demo_account=not settings.demo_mode
                               and demo_account_present(settings))
    if problems:
        for problem in problems:
            print(f"armtrack serve: refusing to start: {problem}", file=sys.stderr)
        return 2
    from armtrack.server.listen import CannotListen, bind_socket

    try:
        sock = bind_socket(settings.host, settings.port, "serve")
    except CannotListen as exc:
        print(f"armtrack serve: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    scheme = "https" if settings.tls_cert else "http"
    port = sock.getsockname()[1]
    print(f"armtrack: serving on {scheme}://{settings.host}:{port} "
          f"(database {shown_url(settings.resolved_database_url())})", flush=True)
    tls = ({"ssl_certfile": str(settings.tls_cert), "ssl_keyfile": str(settings.tls_key)}
           if settings.tls_cert else {})
    # X-Forwarded-For is believed from the configured proxies only (uvicorn's default
    # believes it from 127.0.0.1: any local client, or a proxy there, would choose the
    # address the sign-in limit and the audit log see)
    proxies = trusted_proxies(settings)
    config = uvicorn.Config(create_app(settings), host=settings.host, port=settings.port,
                            **tls, proxy_headers=bool(proxies),
                            forwarded_allow_ips=proxies or None,
                            ws_max_size=settings.max_message_bytes, log_level="info",
                            # kit frames are small JSON: compressing them costs more CPU
                            # than it saves bandwidth on a LAN or Wi-Fi
                            ws_per_message_deflate=False)
    server = uvicorn.Server(config)  # its logging is set up here, so the filter stays
    for name in ("uvicorn.access", "uvicorn.error"):
        logging.getLogger(name).addFilter(RedactTokens())
    logging.getLogger("uvicorn.error").addFilter(DeliberateCutNotError())
    server.run(sockets=[sock])
    return 0 if server.started else 3
