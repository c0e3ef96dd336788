"""A request the database cannot serve answers 503 in words (d3c3a55), to whoever asked,
signed in or not (a sign-in, a kit's upload). The words were the database's own first
line: on PostgreSQL that names the database server's host, address, port and user
('connection to server at "db.clinic.internal" (10.0.3.4), port 5432 failed: FATAL:
password authentication failed for user "armtrack"'), the clinic's network told to
anyone on the internet. The answer says what kind of failure it is and what to do; the
database's words stay in the server's log (and in /healthz, the operator's monitor)."""

from __future__ import annotations

import asyncio
import json
from types import SimpleNamespace

import sqlalchemy as sa
from armtrack.server.plain_text import database_unavailable
from sqlalchemy.exc import OperationalError


def _answer(exc: OperationalError) -> tuple[int, str]:
    request = SimpleNamespace(method="POST", url=SimpleNamespace(path="/api/auth/token"))
    response = asyncio.run(database_unavailable(request, exc))
    return response.status_code, json.loads(response.body)["detail"]


def test_an_unreachable_postgresql_is_not_named_to_the_asker():
    try:  # a real driver's error: nothing listens on port 1
        sa.create_engine("postgresql+psycopg://armtrack:pw@localhost:1/armtrack_clinic"
                         ).connect()
    except OperationalError as exc:
        said = exc
    status, detail = _answer(said)
    print(status, detail)
    assert status == 503
    assert "port 1" not in detail and "127.0.0.1" not in detail and "localhost" not in detail
    assert "cannot reach its database" in detail


def test_a_full_disk_is_said_as_such():
    said = OperationalError("INSERT …", {}, Exception("database or disk is full"))
    status, detail = _answer(said)
    print(status, detail)
    assert status == 503 and "database or disk is full" in detail


def test_healthz_does_not_name_the_database_server(tmp_path):
    """/healthz answers anyone (a monitor, and whoever reaches the proxy): while commits
    fail it said the database's words, PostgreSQL's naming its host and port."""
    from armtrack.server.app import create_app
    from armtrack.server.db.errors import database_words
    from armtrack.server.settings import Settings

    try:
        sa.create_engine("postgresql+psycopg://armtrack:pw@localhost:1/armtrack_clinic"
                         ).connect()
    except OperationalError as exc:
        said = exc
    app = create_app(Settings(data_dir=tmp_path))
    health = next(r.endpoint for r in app.routes if getattr(r, "path", "") == "/healthz")
    failing = {"since": 1.8e9, "reason": database_words(said)}  # as the writer keeps it
    request = SimpleNamespace(app=SimpleNamespace(state=SimpleNamespace(
        services=SimpleNamespace(writer=SimpleNamespace(failing=failing)))))
    response = health(request)
    detail = json.loads(response.body)["detail"]
    print(response.status_code, detail)
    assert response.status_code == 503
    assert "port 1" not in detail and "127.0.0.1" not in detail
    assert "cannot reach its database" in detail
