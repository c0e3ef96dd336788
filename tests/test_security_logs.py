"""What the server writes into its log when the database fails (attack13): nothing a
request stored — no patient's name, no password hash.

Found on a real server (SQLite, another connection holding the database's write lock past
the busy timeout): ``POST /api/patients`` answered 503 in words (d3c3a55), and the log said
``[parameters: (1, 'Zorba Secretname', 'right', 1.7, …)]``; a password change,
``[parameters: ('$argon2id$v=19$m=65536,t=3,p=4$…', 1)]`` — the new password's hash,
which an offline guesser can work on. SQLAlchemy puts a failed statement's parameters
into its error's text, which the 503 handler logs (and any 500's traceback would). The
server's engines now keep them out (``hide_parameters``)."""

from __future__ import annotations

import pytest
from sqlalchemy import text
from sqlalchemy.exc import DBAPIError


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_a_failed_statements_parameters_stay_out_of_its_error(tmp_path, backend):
    from armtrack.server.db.engine import make_engine

    url = (f"sqlite:///{tmp_path / 'armtrack.db'}" if backend == "sqlite"
           else "postgresql+psycopg://nobody@127.0.0.1:1/none")  # the engine's options only
    engine = make_engine(url)
    try:
        if backend == "postgresql":
            assert engine.hide_parameters, "PostgreSQL's engine shows parameters"
            return
        with engine.connect() as connection, pytest.raises(DBAPIError) as failed:
            connection.execute(text("INSERT INTO no_such_table (name, hash) VALUES (:n, :h)"),
                               {"n": "Zorba Secretname", "h": "$argon2id$v=19$secret"})
    finally:
        engine.dispose()
    said = str(failed.value)
    print(f"\nthe error's text: {said!r}")
    assert "no such table" in said  # what the database said stays
    assert "Zorba" not in said and "argon2" not in said
