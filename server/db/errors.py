"""The database's errors the command line says in words (light: no sqlalchemy import)."""


class SchemaError(Exception):
    """The database cannot be brought to this armtrack's schema: the message says why and
    what to do."""
