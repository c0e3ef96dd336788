"""patient targets: a therapist's target range per joint angle and patient

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23 15:09:26.042737
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "patient_targets",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("patient_id", sa.Integer(), nullable=False),
        sa.Column("angle", sa.String(length=40), nullable=False),
        sa.Column("min_deg", sa.Float(), nullable=False),
        sa.Column("max_deg", sa.Float(), nullable=False),
        sa.Column("note", sa.String(length=500), nullable=True),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["patient_id"], ["patients.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("patient_id", "angle", name="uq_patient_targets_patient_angle"),
    )
    with op.batch_alter_table("patient_targets", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_patient_targets_patient_id"), ["patient_id"], unique=False
        )


def downgrade() -> None:
    with op.batch_alter_table("patient_targets", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_patient_targets_patient_id"))
    op.drop_table("patient_targets")
