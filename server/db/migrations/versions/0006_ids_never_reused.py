"""ids never reused: SQLite tables rebuilt with AUTOINCREMENT, counters past every id seen

Without AUTOINCREMENT, SQLite gives a new row the largest id in the table plus one, so the
id of an erased patient (session, kit, therapist …) was given again to the next one, who
then inherited what still named that id: an open live feed or 3D view, the audit trail.
With it, SQLite keeps the largest id ever given (``sqlite_sequence``) and never goes below.
Rows erased before this migration left no such trace; their ids are known from the audit
log, which names patients, sessions, kits and therapists by id: each counter starts past
the largest id the table or the audit log holds.

PostgreSQL needs nothing: its sequences never hand out a value twice.

``sample_blocks`` is not rebuilt: its ids name nothing outside the table, it is the one
large table, and its inserts are the hot path of ingest.

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-02 05:40:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None

#: Tables rebuilt, each with the audit log's column that names its ids (if any).
#: (The tables of 0004 and 0005 were made with AUTOINCREMENT already.)
TABLES = {"therapists": "therapist_id", "access_tokens": None, "patients": "patient_id",
          "devices": "device_id", "sessions": "session_id", "marks": None,
          "estimate_blocks": None, "patient_targets": None, "password_resets": None,
          "audit_log": None}


def upgrade() -> None:
    bind = op.get_bind()
    if bind.dialect.name != "sqlite":
        return
    for table in TABLES:
        with op.batch_alter_table(table, recreate="always",
                                  table_kwargs={"sqlite_autoincrement": True}):
            pass
    for table, audit_column in TABLES.items():
        highest = bind.execute(sa.text(f"SELECT max(id) FROM {table}")).scalar() or 0
        if audit_column is not None:
            seen = bind.execute(sa.text(f"SELECT max({audit_column}) FROM audit_log")
                                ).scalar() or 0
            highest = max(highest, seen)
        bind.execute(sa.text("DELETE FROM sqlite_sequence WHERE name = :t"), {"t": table})
        bind.execute(sa.text("INSERT INTO sqlite_sequence (name, seq) VALUES (:t, :seq)"),
                     {"t": table, "seq": highest})


def downgrade() -> None:
    bind = op.get_bind()
    if bind.dialect.name != "sqlite":
        return
    for table in TABLES:
        with op.batch_alter_table(table, recreate="always",
                                  table_kwargs={"sqlite_autoincrement": False}):
            pass
