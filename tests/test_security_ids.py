"""Issue 17 item 1, the database side: migration 0006 rebuilds a database made before it
(revision 0003) with SQLite's AUTOINCREMENT, keeps every row and every reference (no
cascade from the rebuild), and starts each counter past every id ever given — also past
ids of rows erased before the migration, which only the audit log still names."""

from __future__ import annotations

from armtrack.server.db.engine import make_engine
from armtrack.server.db.migrate import upgrade
from sqlalchemy import text

REBUILT = ("therapists", "access_tokens", "patients", "devices", "sessions", "marks",
           "estimate_blocks", "patient_targets", "password_resets", "audit_log")


def test_an_old_database_is_rebuilt_without_losing_rows_and_never_reuses_ids(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'old.db'}")
    upgrade(engine, "0003")
    with engine.begin() as db:
        run = db.exec_driver_sql
        run("INSERT INTO therapists (id, username, password_hash, created_at, is_admin) "
            "VALUES (1, 'alice', 'x', '2026-01-01', 0)")
        for pid in (1, 2, 3):
            run(f"INSERT INTO patients (id, therapist_id, name, side, height_m, created_at) "
                f"VALUES ({pid}, 1, 'p{pid}', 'right', 1.7, '2026-01-01')")
        run("INSERT INTO devices (id, patient_id, name, token_hash, created_at) "
            "VALUES (4, 2, 'kit', 'h', '2026-01-01')")
        run("INSERT INTO sessions (id, patient_id, device_id, source, status, side, sensors, "
            "metadata, started_at, samples) VALUES (5, 2, 4, 'stream', 'closed', 'right', "
            "'{}', '{}', '2026-01-01', 0)")
        run("INSERT INTO marks (session_id, t, label) VALUES (5, 1.0, 'npose')")
        # patient 9 (session 12, kit 11) was erased long ago: only the audit log names them
        run("INSERT INTO audit_log (at, therapist_id, device_id, action, patient_id, "
            "session_id, route) VALUES ('2026-01-01', 1, 11, 'erased', 9, 12, 'x')")
        run("DELETE FROM patients WHERE id = 3")  # the highest patient, erased
    upgrade(engine)
    with engine.begin() as db:
        run = db.exec_driver_sql
        for table in REBUILT:
            sql = run(f"SELECT sql FROM sqlite_master WHERE type = 'table' "
                      f"AND name = '{table}'").scalar()
            assert "AUTOINCREMENT" in sql, (table, sql)
        # every row and reference is still there (the rebuild cascaded nothing)
        assert run("SELECT id FROM patients ORDER BY id").scalars().all() == [1, 2]
        assert run("SELECT patient_id FROM devices").scalars().all() == [2]
        assert run("SELECT device_id FROM sessions").scalars().all() == [4]
        assert run("SELECT count(*) FROM marks").scalar() == 1
        assert run("PRAGMA foreign_keys").scalar() == 1  # on again after the migration
        # new rows go past every id ever given, the erased ones' included
        run("INSERT INTO patients (therapist_id, name, side, height_m, created_at) "
            "VALUES (1, 'new', 'left', 1.6, '2026-02-01')")
        run("INSERT INTO devices (patient_id, name, token_hash, created_at) "
            "VALUES (1, 'kit', 'h2', '2026-02-01')")
        run("INSERT INTO sessions (patient_id, source, status, side, sensors, metadata, "
            "started_at, samples) VALUES (1, 'stream', 'closed', 'right', '{}', '{}', "
            "'2026-02-01', 0)")
        assert run("SELECT max(id) FROM patients").scalar() == 10
        assert run("SELECT max(id) FROM devices").scalar() == 12
        assert run("SELECT max(id) FROM sessions").scalar() == 13
    # and a row erased now leaves its id used up
    with engine.begin() as db:
        db.execute(text("DELETE FROM patients WHERE id = 10"))
        db.execute(text("INSERT INTO patients (therapist_id, name, side, height_m, "
                        "created_at) VALUES (1, 'next', 'left', 1.6, '2026-02-02')"))
        assert db.execute(text("SELECT max(id) FROM patients")).scalar() == 11
    engine.dispose()


def test_a_new_database_has_autoincrement_from_the_start(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'new.db'}")
    upgrade(engine)
    with engine.connect() as db:
        for table in REBUILT:
            sql = db.exec_driver_sql(
                f"SELECT sql FROM sqlite_master WHERE type = 'table' AND name = '{table}'"
            ).scalar()
            assert "AUTOINCREMENT" in sql, (table, sql)
        indexes = set(db.exec_driver_sql(
            "SELECT name FROM sqlite_master WHERE type = 'index'").scalars())
        assert {"ix_patients_therapist_id", "ix_sessions_status", "ix_audit_log_patient_id",
                "ix_sample_blocks_session_sensor"} <= indexes
    engine.dispose()
