"""The database's errors said in words (light: no sqlalchemy import): the command line's
:class:`SchemaError`, :func:`database_words` for what the database itself said, and which
of its failures waiting mends (a lock, a full disk, a server out of reach: "try again")
and which it does not (:func:`lacks_schema`: a table or column this armtrack needs is
not there — a database of another armtrack version, not upgraded: what to run)."""

import re


class SchemaError(Exception):
    """The database cannot be brought to this armtrack's schema: the message says why and
    what to do."""


class DriverMissing(Exception):
    """The database URL names a driver this environment lacks: the message names what to
    install, with this environment's pip."""


def database_words(exc: BaseException) -> str:
    """What the database said (SQLAlchemy's wrapped driver error: its first line, e.g.
    "database or disk is full"), without SQLAlchemy's statement and link."""
    said = getattr(exc, "orig", None) or exc
    return (str(said).strip().splitlines() or [type(said).__name__])[0]


#: What a database says that may be told to whoever asked: SQLite's words for a full disk,
#: a lock held too long and a file it cannot write, and PostgreSQL's for a full disk.
TOLD_WORDS = ("database or disk is full", "database is locked",
              "attempt to write a readonly database", "disk I/O error",
              "No space left on device")


def told_words(exc: BaseException) -> str:
    """What a failed request's answer says of the database (anyone may have asked: a
    sign-in): ``told`` of what it said."""
    return told(database_words(exc))


def told(words: str) -> str:
    """What an answer to anyone says of the database's ``words`` (``database_words``): the
    words when they are of ``TOLD_WORDS``; else only the kind of failure, since
    PostgreSQL's first line names its host, address, port and user."""
    if any(told in words for told in TOLD_WORDS):
        return f"its database says \"{words}\""
    if "connect" in words.lower():
        return "it cannot reach its database"
    return "its database failed"


#: What SQLite and PostgreSQL say when a table or column is not there: "no such table:
#: x", "no such column: x.y", "table x has no column named y"; 'relation "x" does not
#: exist', 'column x.y does not exist', 'column "y" of relation "x" does not exist'.
_LACKING = re.compile(r"no such (table|column)\b|has no column named|"
                      r"\b(relation|column) \S+ (of relation \S+ )?does not exist")

#: What an answer says of a database that lacks what this armtrack needs, and what to
#: run: no table, column, statement, path or host is named (anyone may have asked).
NOT_UPGRADED = (
    "its database lacks a table or column this version of armtrack needs: it was made or "
    "restored by another version and not upgraded. Waiting will not mend this: the "
    "clinic's IT should stop armtrack and start it again with `armtrack serve`, which "
    "upgrades the database as it starts or says why it cannot (docs/operator.md, "
    "Upgrading)")


def lacks_schema(words: str) -> bool:
    """Whether the database's ``words`` (``database_words``) say a table or column is not
    there: waiting does not mend it, an upgrade does."""
    return _LACKING.search(words) is not None
