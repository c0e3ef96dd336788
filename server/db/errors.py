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
