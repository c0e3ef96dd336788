"""A clinic upgrades: the new armtrack starts on last month's database (docs/operator.md,
"Upgrading"). An upgrade cut short (the disk full while migration 0006 rebuilds tables)
changes nothing, and the next start, with room, migrates and keeps every row; a database
left by a newer armtrack (a roll-back) is refused in words, not a traceback. Real
``armtrack serve`` processes on a real SQLite file."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import httpx
import pytest
from armtrack.server.auth import hash_password, hash_token, new_token
from armtrack.server.db.engine import make_engine
from armtrack.server.db.migrate import current_revision, head_revision, upgrade
from server_support import PASSWORD, ServerProcess
from sqlalchemy import event

TABLES = ("therapists", "patients", "devices", "sessions", "marks", "audit_log")


def last_months_database(path) -> str:
    """A database as armtrack of November made it (schema 0003): a therapist ``alice``,
    two patients, a kit, a closed session with marks; returns the kit's token."""
    engine = make_engine(f"sqlite:///{path}")
    upgrade(engine, "0003")
    token, token_hash = new_token("dev_")
    with engine.begin() as db:
        run = db.exec_driver_sql
        run("INSERT INTO therapists (id, username, password_hash, created_at, is_admin) "
            "VALUES (1, 'alice', ?, '2026-11-20', 0)", (hash_password(PASSWORD),))
        for pid in (1, 2):
            run(f"INSERT INTO patients (id, therapist_id, name, side, height_m, created_at) "
                f"VALUES ({pid}, 1, 'p{pid}', 'right', 1.7, '2026-11-20')")
        run("INSERT INTO devices (id, patient_id, name, token_hash, created_at) "
            "VALUES (1, 2, 'kit', ?, '2026-11-20')", (token_hash,))
        run("INSERT INTO sessions (id, patient_id, device_id, source, status, side, sensors, "
            "metadata, started_at, ended_at, samples) VALUES (1, 2, 1, 'stream', 'closed', "
            "'right', '{}', '{}', '2026-11-21', '2026-11-21', 0)")
        for t in (1.0, 2.0, 3.0):
            run(f"INSERT INTO marks (session_id, t, label) VALUES (1, {t}, 'npose')")
        run("INSERT INTO audit_log (at, therapist_id, action, patient_id, route) "
            "VALUES ('2026-11-21', 1, 'read', 2, 'x')")
    engine.dispose()
    assert hash_token(token) == token_hash
    return token


def counts(path) -> dict[str, int]:
    with sqlite3.connect(path) as db:
        return {t: db.execute(f"SELECT count(*) FROM {t}").fetchone()[0] for t in TABLES}


def test_an_upgrade_cut_short_by_a_full_disk_changes_nothing_and_runs_again(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    path = data / "armtrack.db"
    token = last_months_database(path)
    before = counts(path)
    pages = sqlite3.connect(path).execute("PRAGMA page_count").fetchone()[0]
    # the disk fills up while the migrations run: SQLite's own limit on the file's size
    # gives the error a full disk gives (SQLITE_FULL): 15 pages more than the file has runs
    # out during 0006's rebuild, 0004 and 0005 done (39 pages; 30 more hold the upgrade)
    engine = make_engine(f"sqlite:///{path}")
    event.listen(engine, "connect",
                 lambda dbapi, _record: dbapi.execute(f"PRAGMA max_page_count={pages + 15}"))
    with pytest.raises(Exception, match="full") as failed:
        upgrade(engine)
    print("the cut-short upgrade:", str(failed.value).splitlines()[0])
    revision = current_revision(engine)
    engine.dispose()
    with sqlite3.connect(path) as db:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    print("after it: revision", revision, "tables", sorted(tables))
    assert revision == "0003", "a failed upgrade left the database half migrated"
    assert "programs" not in tables and not any(t.startswith("_alembic_tmp") for t in tables)
    assert counts(path) == before

    # the operator makes room and starts the new armtrack again, as operator.md says
    server = ServerProcess(data)
    server.start(timeout=180)
    try:
        assert current_revision(make_engine(server.database_url)) == head_revision()
        log = server.log.read_text()
        assert f"armtrack: database migrated from schema 0003 to {head_revision()}" in log, log
        assert counts(path) == before, (counts(path), before)
        api = httpx.Client(base_url=server.url, timeout=60)
        signed = api.post("/api/auth/token", data={"username": "alice", "password": PASSWORD})
        assert signed.status_code == 200, signed.text
        api.headers["Authorization"] = f"Bearer {signed.json()['access_token']}"
        assert sorted(p["name"] for p in api.get("/api/patients").json()) == ["p1", "p2"]
        assert [s["id"] for s in api.get("/api/patients/2/sessions").json()] == [1]
        kits = httpx.get(server.url + "/api/device/today",
                         headers={"Authorization": f"Bearer {token}"}, timeout=60)
        assert kits.status_code == 200, kits.text  # last month's kit token still works
    finally:
        server.stop()


def test_a_database_of_a_newer_armtrack_is_refused_in_words(tmp_path):
    """Going back to an older armtrack after an upgrade: its migrations do not know the
    database's schema. It says so and what to do, starts nothing, changes nothing."""
    data = tmp_path / "data"
    data.mkdir()
    engine = make_engine(f"sqlite:///{data / 'armtrack.db'}")
    upgrade(engine)
    with engine.begin() as db:
        db.exec_driver_sql("UPDATE alembic_version SET version_num = '0099'")
    engine.dispose()
    server = ServerProcess(data)
    for command in (["serve", "--port", str(server.port)], ["create-user", "ada",
                                                            "--password", PASSWORD]):
        done = server.armtrack(*command, timeout=120)
        print(done.stderr)
        assert done.returncode == 2, done.stderr[-2000:]
        assert "Traceback" not in done.stderr
        assert "schema 0099" in done.stderr and "newer armtrack" in done.stderr
        assert f"this armtrack's is {head_revision()}" in done.stderr
        assert "backup taken before the upgrade" in done.stderr
    assert current_revision(make_engine(f"sqlite:///{data / 'armtrack.db'}")) == "0099"
    guide = (Path(__file__).parents[1] / "docs" / "operator.md").read_text("utf-8")
    assert "\n## Upgrading\n" in guide  # the section the message names


def test_a_migration_waits_for_another_writer_instead_of_failing(tmp_path):
    """A migration run while another program writes to the same SQLite file (a running
    server stamping "last seen", the test of the not-upgraded words taking the schema back
    behind it) waits its turn. It began with a plain ``BEGIN``: it read the schema, then
    wanted to write, and a write committed by the other in between made SQLite answer
    "database is locked" at once, without the busy timeout's wait (WAL mode cannot move a
    read snapshot forward into a write): CI's run failed so. Now it takes the write lock
    first (``BEGIN IMMEDIATE``), so the busy timeout applies."""
    import threading
    import time

    from alembic import command
    from armtrack.server.db.migrate import alembic_config

    path = tmp_path / "armtrack.db"
    engine = make_engine(f"sqlite:///{path}")
    upgrade(engine)
    with engine.begin() as db:
        db.exec_driver_sql("CREATE TABLE scratch (n INTEGER)")
    stop = threading.Event()
    writes = []

    def other_writer() -> None:
        other = sqlite3.connect(path, timeout=30)
        while not stop.is_set():
            other.execute("INSERT INTO scratch VALUES (1)")
            other.commit()
            writes.append(1)
            time.sleep(0.001)
        other.close()

    writer = threading.Thread(target=other_writer)
    writer.start()
    while len(writes) < 20:  # the other program is writing
        time.sleep(0.01)
    at_start = len(writes)
    try:
        for revision in ("0009", "head", "0008", "head"):
            move = command.upgrade if revision == "head" else command.downgrade
            move(alembic_config(engine), revision)
    finally:
        stop.set()
        writer.join()
        engine.dispose()
    print(f"\n{len(writes) - at_start} writes by the other program between the migrations")
    assert len(writes) > at_start
    assert current_revision(make_engine(f"sqlite:///{path}")) == head_revision()


def test_create_user_on_last_months_database_says_it_upgraded_it(tmp_path):
    """Found following docs/operator.md's Upgrading as a clinic's IT person: after
    installing the new version, ``armtrack create-user`` (a second therapist, before
    starting the server) migrated the database from schema 0003 silently, so the
    upgrade the guide says "says so in its log" left no word anywhere (and an IT person
    who had skipped step 1's backup would not learn that the old version could no
    longer open it). Now it says so, as ``armtrack serve`` does."""
    data = tmp_path / "data"
    data.mkdir()
    last_months_database(data / "armtrack.db")
    server = ServerProcess(data)
    done = server.armtrack("create-user", "bob", "--password", "a long password")
    print(done.stdout, done.stderr)
    assert done.returncode == 0, done.stderr
    assert f"database migrated from schema 0003 to {head_revision()}" in done.stdout
    assert "created therapist 'bob'" in done.stdout
    again = server.armtrack("create-user", "carl", "--password", "a long password")
    assert again.returncode == 0 and "migrated" not in again.stdout  # once only


def test_reprocess_on_last_months_database_says_it_upgraded_it(tmp_path):
    """``armtrack reprocess`` migrates the database too (before the server's start, after
    an upgrade): it did so without a word, as create-user did (review19)."""
    data = tmp_path / "data"
    data.mkdir()
    last_months_database(data / "armtrack.db")
    done = ServerProcess(data).armtrack("reprocess", "999")
    print(done.stdout, done.stderr)
    assert f"database migrated from schema 0003 to {head_revision()}" in done.stdout
    assert "no session 999" in done.stderr
