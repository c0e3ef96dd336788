"""Alembic migrations, run from code: the server brings its database to the newest
schema on start (``upgrade``). alembic is imported only when a migration runs:
``ensure_current`` (``armtrack create-user``) first checks the database's revision
against the newest migration file, which costs a query, not alembic's ~0.2 s import.

An upgrade is all or nothing (migrations/env.py). A database this armtrack cannot bring to
its schema — one a newer armtrack migrated (going back after an upgrade), or an upgrade
that failed (a full disk) — raises :class:`SchemaError` in words the operator can act on;
the command line prints it (exit code 2)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, inspect, text
from sqlalchemy.exc import OperationalError

from .errors import SchemaError

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


def upgrade(engine: Engine, revision: str = "head") -> tuple[str | None, str | None]:
    """Migrate the database behind ``engine`` to ``revision`` (default: the newest);
    returns its revision before and after (None: a new database). :class:`SchemaError` if
    it is of a newer armtrack or the upgrade fails (then nothing of it is stored)."""
    from alembic import command

    at = current_revision(engine)
    known = _revisions()
    if at is not None and known is not None and at not in known:
        raise SchemaError(
            f"the database is at schema {at}, which a newer armtrack made: this armtrack's "
            f"is {head_revision()} and it cannot read it. Run the armtrack that upgraded it, "
            f"or restore the backup taken before the upgrade (docs/operator.md, Upgrading)")
    try:
        command.upgrade(alembic_config(engine), revision)
    except OperationalError as exc:
        raise SchemaError(
            f"the database could not be migrated from schema {at or 'none'} to "
            f"{head_revision()}: {exc.orig}. Nothing of the upgrade was stored (it is still "
            f"at schema {at or 'none'}); mend that (a full disk: make room) and start again"
        ) from exc
    return at, current_revision(engine)


def head_revision() -> str | None:
    """The newest migration's id: the one no other names as its ``down_revision`` (the
    chain is linear), read from the files' ``revision = "…"`` lines; None if that reading
    is ambiguous (then ``ensure_current`` lets alembic decide)."""
    chain = _chain()
    if chain is None:
        return None
    heads = set(chain) - set(chain.values())
    return heads.pop() if len(heads) == 1 else None


def _chain() -> dict[str, str | None] | None:
    """Each migration's id → its ``down_revision``, from the files; None if a file's
    ``revision = "…"`` line cannot be read."""
    chain = {}
    for path in (MIGRATIONS / "versions").glob("[0-9]*.py"):
        found = dict((k, v or None) for k, v in _REVISION.findall(path.read_text("utf-8")))
        if "revision" not in found:
            return None
        chain[found["revision"]] = found.get("down_revision")
    return chain


def _revisions() -> set[str] | None:
    """The ids of this armtrack's migrations (None: unreadable, alembic decides)."""
    chain = _chain()
    return None if chain is None else set(chain)


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None: never migrated)."""
    with engine.connect() as connection:
        if not inspect(connection).has_table("alembic_version"):
            return None
        return connection.execute(text("SELECT version_num FROM alembic_version")).scalar()


def schema_words(engine: Engine) -> str | None:
    """None when the database is at this armtrack's schema (or that cannot be told: the
    migration files unreadable); else what is wrong and what to run, in words for the
    clinic's IT that name no path or host (``/healthz``). A query; raises what the
    database raises (a lock, a server out of reach)."""
    head = head_revision()
    at = current_revision(engine)
    if head is None or at == head:
        return None
    known = _revisions()
    if at is not None and known is not None and at not in known:
        return (f"the database is at schema {at}, which a newer armtrack made; this one's is "
                f"{head}. Run the armtrack that upgraded it, or restore the backup taken "
                f"before the upgrade (docs/operator.md, Upgrading)")
    return (f"the database is at schema {at or 'none'}, an older armtrack's, and was not "
            f"upgraded; this one's is {head}. Stop armtrack and start it again with "
            f"`armtrack serve`, which upgrades the database as it starts "
            f"(docs/operator.md, Upgrading)")


def migrated_words(before: str | None, after: str | None) -> str | None:
    """The line every command that upgraded an existing database prints (``serve``,
    ``create-user``, ``reprocess``: docs/operator.md, Upgrading), or None when it did not
    (a new database, or nothing to do)."""
    if before is None or before == after:
        return None
    return f"armtrack: database migrated from schema {before} to {after}"


def ensure_current(engine: Engine) -> tuple[str | None, str | None] | None:
    """Migrate the database to the newest schema if it is not there: the schemas before
    and after when it did (before ``None``: a new database), else ``None``."""
    head = head_revision()
    if head is not None and current_revision(engine) == head:
        return None
    return upgrade(engine)
