"""The database's errors said in words (light: no sqlalchemy import): the command line's
:class:`SchemaError`, and :func:`database_words` for what the database itself said."""


class SchemaError(Exception):
    """The database cannot be brought to this armtrack's schema: the message says why and
    what to do."""


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
