"""a kit remembers its sensors' gyroscope biases (docs/gyro-bias-memory.md): the table of
each kit's remembered biases, and the biases a session's filters started from

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-02 16:00:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "kit_gyro_biases",
        sa.Column("device_id", sa.Integer(), nullable=False),
        sa.Column("sensor", sa.String(length=12), nullable=False),
        sa.Column("bias_x", sa.Float(), nullable=False),
        sa.Column("bias_y", sa.Float(), nullable=False),
        sa.Column("bias_z", sa.Float(), nullable=False),
        sa.Column("learnt", sa.String(length=12), nullable=False),
        sa.Column("still_s", sa.Float(), nullable=False),
        sa.Column("age_s", sa.Float(), nullable=False),
        sa.Column("session_id", sa.Integer(), nullable=True),
        sa.Column("session_started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["device_id"], ["devices.id"], ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["session_id"], ["sessions.id"], ondelete="SET NULL"),
        sa.PrimaryKeyConstraint("device_id", "sensor"),
    )
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("gyro_bias_prior", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_column("gyro_bias_prior")
    op.drop_table("kit_gyro_biases")
