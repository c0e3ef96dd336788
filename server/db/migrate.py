"""Alembic migrations, run from code: the server brings its database to the newest
schema on start (``upgrade``). alembic is imported only when a migration runs:
``ensure_current`` (``armtrack create-user``) first checks the database's revision
against the newest migration file, which costs a query, not alembic's ~0.2 s import."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, inspect, text

if TYPE_CHECKING:
    from alembic.config import Config

MIGRATIONS = Path(__file__).with_name("migrations")
_REVISION = re.compile(r'^(down_revision|revision)\s*=\s*(?:"([^"]*)"|None)', re.MULTILINE)


def alembic_config(engine: Engine) -> Config:
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["engine"] = engine
    return config


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Migrate the database behind ``engine`` to ``revision`` (default: the newest)."""
    from alembic import command

    command.upgrade(alembic_config(engine), revision)


def head_revision() -> str | None:
    """The newest migration's id: the one no other names as its ``down_revision`` (the
    chain is linear), read from the files' ``revision = "…"`` lines; None if that reading
    is ambiguous (then ``ensure_current`` lets alembic decide)."""
    revisions, parents = set(), set()
    for path in (MIGRATIONS / "versions").glob("[0-9]*.py"):
        found = dict((k, v or None) for k, v in _REVISION.findall(path.read_text("utf-8")))
        if "revision" not in found:
            return None
        revisions.add(found["revision"])
        parents.add(found.get("down_revision"))
    heads = revisions - parents
    return heads.pop() if len(heads) == 1 else None


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None: never migrated)."""
    with engine.connect() as connection:
        if not inspect(connection).has_table("alembic_version"):
            return None
        return connection.execute(text("SELECT version_num FROM alembic_version")).scalar()


def ensure_current(engine: Engine) -> bool:
    """Migrate the database to the newest schema if it is not there; True if it migrated."""
    head = head_revision()
    if head is not None and current_revision(engine) == head:
        return False
    upgrade(engine)
    return True
