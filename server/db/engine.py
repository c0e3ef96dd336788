"""Database engines and sessions. SQLite (the default) runs in WAL mode with foreign keys
on and full fsync, so an acked sample survives a crash, and ``secure_delete`` (an erased
patient's data is overwritten in the file); any other SQLAlchemy URL
(PostgreSQL) is used as it is."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import sessionmaker

from .errors import DriverMissing


def owner_only_file(path: Path) -> None:
    """The SQLite file readable and writable by its owner only (0600), made empty if
    missing (SQLite gives its -wal and -shm files the database's mode); its folder is made
    if missing, 0700 when new. A wider mode of an existing file is narrowed: the database
    holds patients' data."""
    if not path.parent.exists():
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.close(os.open(path, os.O_RDWR | os.O_CREAT, 0o600))
    if path.stat().st_mode & 0o077:
        os.chmod(path, 0o600)


def driver_missing_words(backend: str, exc: ModuleNotFoundError) -> str:
    """What to install when the database URL's driver is missing: PostgreSQL's comes with
    the ``postgres`` extra (pyproject.toml), installed with this environment's pip."""
    pip = Path(sys.executable).parent / "pip"
    module = exc.name or str(exc)
    if backend == "postgresql":
        return (f"the database URL is PostgreSQL's but its driver, {module}, is not installed "
                f"in this environment: {pip} install 'psycopg[binary]>=3.1' (what the extra "
                "armtrack[postgres] holds; docs/operator.md, PostgreSQL)")
    return (f"the database URL's driver for {backend}, {module}, is not installed in this "
            f"environment: install it with {pip} install, or use SQLite or PostgreSQL")


def make_engine(url: str) -> Engine:
    """An engine for ``url``; for an SQLite file its folder is made if missing. A failed
    statement's parameters stay out of its error's text (``hide_parameters``), which the
    server logs: they are what a request stored (a patient's name, a new password's
    hash; attack13 found both in the log of a database locked past its busy timeout)."""
    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite":
        try:
            return create_engine(url, pool_pre_ping=True, hide_parameters=True)
        except ModuleNotFoundError as exc:  # else a traceback ending in "No module named …"
            raise DriverMissing(driver_missing_words(parsed.get_backend_name(), exc)) from exc
    if parsed.database and parsed.database != ":memory:":
        owner_only_file(Path(parsed.database))
    engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30},
                           hide_parameters=True)

    @event.listens_for(engine, "connect")
    def _sqlite_pragmas(dbapi_connection, _record) -> None:  # pragma: no cover - trivial
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=FULL")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute("PRAGMA busy_timeout=30000")
        cursor.execute("PRAGMA secure_delete=ON")  # erased data is overwritten, not left
        cursor.close()

    return engine


def make_sessionmaker(engine: Engine) -> sessionmaker:
    return sessionmaker(engine, expire_on_commit=False)
