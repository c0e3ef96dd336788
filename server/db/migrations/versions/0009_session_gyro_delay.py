"""a kit declares how far its gyroscopes lag its accelerometers (docs/extensions/
gyro-delay.md): the delay a session's filters take, as its hello or file declared it

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-03 03:00:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("gyro_delay_s", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_column("gyro_delay_s")
