"""``armtrack serve``: the server under uvicorn, settings from the environment
(``ARMTRACK_…``) and these flags."""

from __future__ import annotations

import argparse
import logging
import re
from pathlib import Path

#: ``token=…`` in a logged URL (kits that cannot set headers put their token there).
TOKEN_IN_URL = re.compile(r"(token=)[^&\s\"']+")


class RedactTokens(logging.Filter):
    """Keeps bearer tokens given in URLs out of the logs."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.args:
            record.args = tuple(TOKEN_IN_URL.sub(r"\1***", a) if isinstance(a, str) else a
                                for a in record.args)
        if isinstance(record.msg, str):
            record.msg = TOKEN_IN_URL.sub(r"\1***", record.msg)
        return True


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="address to listen on (ARMTRACK_HOST, default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port (ARMTRACK_PORT, default 8000)")
    parser.add_argument("--data-dir", type=Path,
                        help="folder for the database (ARMTRACK_DATA_DIR, default ./armtrack-data)")
    parser.add_argument("--database-url", help="SQLAlchemy URL (ARMTRACK_DATABASE_URL)")


def settings_from(args: argparse.Namespace):
    from armtrack.server.settings import Settings

    given = {k: v for k, v in (("host", args.host), ("port", args.port),
                               ("data_dir", args.data_dir), ("database_url", args.database_url))
             if v is not None}
    return Settings(**given)


def run(args: argparse.Namespace) -> int:
    import uvicorn
    from armtrack.server.app import create_app

    settings = settings_from(args)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    print(f"armtrack: serving on http://{settings.host}:{settings.port} "
          f"(database {settings.resolved_database_url()})", flush=True)
    config = uvicorn.Config(create_app(settings), host=settings.host, port=settings.port,
                            ws_max_size=settings.max_message_bytes, log_level="info",
                            # kit frames are small JSON: compressing them costs more CPU
                            # than it saves bandwidth on a LAN or Wi-Fi
                            ws_per_message_deflate=False)
    server = uvicorn.Server(config)  # its logging is set up here, so the filter stays
    for name in ("uvicorn.access", "uvicorn.error"):
        logging.getLogger(name).addFilter(RedactTokens())
    server.run()
    return 0
