"""``armtrack backup FILE``: a consistent copy of the SQLite database, taken while the
server runs (SQLite's online backup API: one read transaction, so the copy is the
database as of one moment; kits keep streaming meanwhile, WAL mode lets writers go on).
The copy is checked (``PRAGMA integrity_check``) and written owner-only, whole or not
at all. PostgreSQL is backed up with its own tools (``pg_dump``; see docs/operator.md)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from .serve import add_database_arguments

HELP = "copy the database while the server runs (SQLite; PostgreSQL: pg_dump)"
DESCRIPTION = ("Writes a consistent copy of the server's SQLite database to FILE while the "
               "server keeps running (SQLite's online backup): the sessions as of that "
               "moment; samples acked after it are not in it. Restore: stop the server, put "
               "the copy in place of armtrack.db (without the old -wal/-shm files), start "
               "it. See docs/operator.md.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="where to write the copy (must not exist)")
    add_database_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import sqlite3
    import tempfile
    import time

    from sqlalchemy.engine import make_url

    from .serve import settings_from

    url = make_url(settings_from(args).resolved_database_url())
    if url.get_backend_name() != "sqlite":
        plain = url.set(drivername="postgresql", password=None).render_as_string()
        print("armtrack backup: the database is not SQLite; back PostgreSQL up with "
              f"pg_dump: (umask 077; pg_dump --format=custom --file={args.file} '{plain}') "
              "(umask 077: the dump readable by its owner only; the password "
              "from PGPASSWORD or ~/.pgpass; docs/operator.md, Backups)", file=sys.stderr)
        return 2
    source = Path(url.database or "")
    if not source.is_file():
        print(f"armtrack backup: no database at {source} (check --data-dir or "
              "ARMTRACK_DATABASE_URL)", file=sys.stderr)
        return 2
    target = args.file.resolve()
    if target.exists():
        print(f"armtrack backup: {args.file} exists already; give a new file name",
              file=sys.stderr)
        return 2
    started = time.monotonic()
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    os.close(fd)  # mkstemp's file is 0600; sqlite writes into it
    try:
        src = sqlite3.connect(f"file:{source}?mode=ro", uri=True, timeout=30)
        dst = sqlite3.connect(tmp)
        try:
            src.backup(dst)  # all pages in one step: one snapshot, whatever writes go on
            check = dst.execute("PRAGMA integrity_check").fetchone()[0]
            sessions = dst.execute("SELECT count(*) FROM sessions").fetchone()[0]
        finally:
            dst.close()
            src.close()
        if check != "ok":
            raise sqlite3.DatabaseError(f"the copy fails its integrity check: {check}")
        os.chmod(tmp, 0o600)
        os.replace(tmp, target)
    except sqlite3.Error as exc:
        Path(tmp).unlink(missing_ok=True)
        print(f"armtrack backup: {exc}", file=sys.stderr)
        return 1
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    size = target.stat().st_size
    print(f"backed up {source} to {args.file} ({size / 1e6:.1f} MB, {sessions} sessions, "
          f"{time.monotonic() - started:.1f} s)")
    return 0
