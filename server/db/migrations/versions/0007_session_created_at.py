"""sessions.created_at: when the server stored the session (a streamed session's start,
an upload's arrival — not the time the file says it was recorded), so that a kit's new
sessions in the last hour count its uploads too (ARMTRACK_MAX_NEW_SESSIONS_PER_KIT_HOUR).
Sessions stored before take their start.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-02 16:20:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # ADD COLUMN and CREATE INDEX: no table rebuild on SQLite (AUTOINCREMENT kept)
    op.add_column("sessions", sa.Column("created_at", sa.DateTime(timezone=True),
                                        nullable=True))
    op.execute("UPDATE sessions SET created_at = started_at")
    op.create_index("ix_sessions_device_created", "sessions", ["device_id", "created_at"],
                    unique=False)


def downgrade() -> None:
    op.drop_index("ix_sessions_device_created", table_name="sessions")
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_column("created_at")
