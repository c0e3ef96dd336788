"""A database error that waiting does not mend says what to run, not "try again" (the
last session's product gap). Every ``OperationalError`` answered 503 "Try again in a few
minutes", SQLite's "no such table" / "no such column" included, and PostgreSQL's missing
column (a ``ProgrammingError``) was a bare 500 "Internal Server Error": a database of an
older armtrack that was not upgraded (a backup restored behind a running server, an
instance left on another version) had the clinic's IT wait for what waiting will not fix.
And the patients page said nothing at all of a failed list (an empty card: its load's
error went unhandled). Now such an answer says what the database lacks in words (no
table, column, SQL, path or host) and what to run (docs/operator.md, Upgrading); /healthz
says it to the monitor, with the schemas; the patients page shows the server's words
where the list would be; a lock, a full disk or a database out of reach still says try
again (503). A real server on a real SQLite file and on a real PostgreSQL (``eval
"$(.ci/postgres start)"``), the schema taken back to 0009 behind its back by alembic's own
downgrade, the page in Debian's chromium at 390 px."""

from __future__ import annotations

import httpx
import pytest
from browser_helpers import need_browser, page_at, sign_in_as
from conftest import fresh_postgres_database
from server_support import ServerProcess

sync_api = need_browser()

#: Words that must not reach whoever asked: SQL, the missing column's name, where the
#: database is.
LEAKS = ("SELECT", "discharged_at", "patients.", "sqlite", "psycopg", "127.0.0.1",
         "localhost", ".db")


@pytest.fixture(params=["sqlite", "postgresql"])
def server(request, tmp_path):
    env = {}
    if request.param == "postgresql":
        env["ARMTRACK_DATABASE_URL"] = fresh_postgres_database(
            request.getfixturevalue("postgres_url"))
    server = ServerProcess(tmp_path / "data", env)
    server.create_user("alice")
    server.start(timeout=180)
    yield server
    server.stop()


def _downgrade(server: ServerProcess, revision: str) -> None:
    """Take the database back to ``revision`` behind the running server (what restoring
    an older armtrack's backup does), with alembic's own downgrade."""
    from alembic import command
    from armtrack.server.db.engine import make_engine
    from armtrack.server.db.migrate import alembic_config

    engine = make_engine(server.database_url)  # SQLite: the server's busy timeout
    try:
        command.downgrade(alembic_config(engine), revision)
    finally:
        engine.dispose()


def test_a_database_not_upgraded_says_what_to_run(server):
    api = server.client("alice")
    api.patient("Before The Restore")
    assert api.http.get("/api/patients").status_code == 200
    _downgrade(server, "0009")

    answer = api.http.get("/api/patients")
    detail = answer.json()["detail"]
    health = httpx.get(server.url + "/healthz", timeout=30)
    print(f"\n{server.database_url.split(':')[0]}: {answer.status_code} {detail}\n"
          f"/healthz {health.status_code} {health.json()}")
    assert answer.status_code == 500 and "Retry-After" not in answer.headers
    assert "try again" not in detail.lower()
    assert "armtrack serve" in detail and "Upgrading" in detail
    assert not [w for w in LEAKS if w in detail], detail
    assert str(server.data_dir) not in detail
    assert health.status_code == 503
    said = health.json()
    assert said["status"] == "database not upgraded"
    assert "schema 0009" in said["detail"] and "0010" in said["detail"]
    assert "armtrack serve" in said["detail"]
    assert not [w for w in LEAKS if w in said["detail"]] and str(server.data_dir) not in \
        said["detail"]

    with page_at(390) as page:
        sign_in_as(page, server.url, "alice")
        sync_api.expect(page.locator("body")).to_contain_text("armtrack serve", timeout=20_000)
        shown = page.locator("body").inner_text()
        page.screenshot(path=str(server.data_dir.parent / "patients-not-upgraded.png"),
                        full_page=True)
        print(f"patients page at 390 px: {server.data_dir.parent / 'patients-not-upgraded.png'}")
    assert "try again" not in shown.lower()

    # what the words say to run mends it: the server upgrades the database on start
    server.stop()
    server.start(timeout=180)
    assert [p["name"] for p in api.http.get("/api/patients").json()] == ["Before The Restore"]
    assert httpx.get(server.url + "/healthz", timeout=30).json() == {"status": "ok"}


def test_a_lock_still_says_try_again(tmp_path):
    """SQLite locked past the busy timeout (another program holding its write lock): the
    503 "try again" of before, and /healthz still ok (waiting mends it)."""
    import sqlite3

    # the busy timeout 0.3 s by the test hook (30 s in production: test_reliability_faults)
    server = ServerProcess(tmp_path / "data", {"TEST_SQLITE_BUSY_MS": "300"})
    server.create_user("alice")
    server.start(timeout=180)
    try:
        api = server.client("alice")
        holder = sqlite3.connect(server.data_dir / "armtrack.db", timeout=0)
        holder.execute("BEGIN IMMEDIATE")
        try:
            answer = api.http.post("/api/patients", json={"name": "Locked Out",
                                                          "side": "right", "height_m": 1.7})
        finally:
            holder.rollback()
            holder.close()
        print(f"\n{answer.status_code} {answer.json()}")
        assert answer.status_code == 503 and "Retry-After" in answer.headers
        assert "try again" in answer.json()["detail"].lower()
        assert httpx.get(server.url + "/healthz", timeout=30).json() == {"status": "ok"}
    finally:
        server.stop()
