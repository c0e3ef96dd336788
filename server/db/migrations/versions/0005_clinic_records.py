"""clinic records: the therapist's full name, the patient's clinic number and date of
birth, and every version of a patient's targets (the target in force at a session's time)

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-02 05:30:00
"""

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("therapists", schema=None) as batch_op:
        batch_op.add_column(sa.Column("full_name", sa.String(length=200), nullable=True))
    with op.batch_alter_table("patients", schema=None) as batch_op:
        batch_op.add_column(sa.Column("clinic_number", sa.String(length=64), nullable=True))
        batch_op.add_column(sa.Column("date_of_birth", sa.Date(), nullable=True))
    versions = op.create_table(
        "patient_target_versions",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("patient_id", sa.Integer(), nullable=False),
        sa.Column("angle", sa.String(length=40), nullable=False),
        sa.Column("min_deg", sa.Float(), nullable=True),
        sa.Column("max_deg", sa.Float(), nullable=True),
        sa.Column("note", sa.String(length=500), nullable=True),
        sa.Column("set_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("set_by", sa.Integer(), nullable=True),
        sa.ForeignKeyConstraint(["patient_id"], ["patients.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
        sqlite_autoincrement=True,
    )
    with op.batch_alter_table("patient_target_versions", schema=None) as batch_op:
        batch_op.create_index("ix_patient_target_versions_patient_angle_set",
                              ["patient_id", "angle", "set_at"], unique=False)
    # today's targets become their first version, in force since they were last set
    targets = sa.table("patient_targets", sa.column("patient_id"), sa.column("angle"),
                       sa.column("min_deg"), sa.column("max_deg"), sa.column("note"),
                       sa.column("updated_at"))
    op.execute(versions.insert().from_select(
        ["patient_id", "angle", "min_deg", "max_deg", "note", "set_at"],
        sa.select(targets.c.patient_id, targets.c.angle, targets.c.min_deg,
                  targets.c.max_deg, targets.c.note, targets.c.updated_at)))


def downgrade() -> None:
    with op.batch_alter_table("patient_target_versions", schema=None) as batch_op:
        batch_op.drop_index("ix_patient_target_versions_patient_angle_set")
    op.drop_table("patient_target_versions")
    with op.batch_alter_table("patients", schema=None) as batch_op:
        batch_op.drop_column("date_of_birth")
        batch_op.drop_column("clinic_number")
    with op.batch_alter_table("therapists", schema=None) as batch_op:
        batch_op.drop_column("full_name")
