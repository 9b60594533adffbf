"""Families of CMRTs (a request whose runs are jobs), where a job's search started, and a
finished job's result document.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-05
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("start", sa.JSON(), nullable=True))
        batch.add_column(sa.Column("result", sa.JSON(), nullable=True))
    op.create_table(
        "families",
        sa.Column("id", sa.String(length=36), nullable=False),
        sa.Column("family", sa.String(length=100), nullable=False),
        sa.Column("param", sa.String(length=200), nullable=False),
        sa.Column("spec", sa.JSON(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("cancel_requested", sa.Boolean(), nullable=False),
        sa.Column("probes", sa.JSON(), nullable=True),
        sa.Column("report", sa.JSON(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_families")),
    )
    op.create_index(op.f("ix_families_family"), "families", ["family"])
    op.create_index(op.f("ix_families_status"), "families", ["status"])
    op.create_index(op.f("ix_families_created_at"), "families", ["created_at"])
    op.create_table(
        "family_runs",
        sa.Column("family_id", sa.String(length=36), nullable=False),
        sa.Column("run_id", sa.String(length=100), nullable=False),
        sa.Column("job_id", sa.String(length=36), nullable=False),
        sa.ForeignKeyConstraint(["family_id"], ["families.id"], ondelete="CASCADE",
                                name=op.f("fk_family_runs_family_id_families")),
        sa.ForeignKeyConstraint(["job_id"], ["jobs.id"], ondelete="CASCADE",
                                name=op.f("fk_family_runs_job_id_jobs")),
        sa.PrimaryKeyConstraint("family_id", "run_id", name=op.f("pk_family_runs")),
    )
    op.create_index(op.f("ix_family_runs_job_id"), "family_runs", ["job_id"])


def downgrade() -> None:
    op.drop_index(op.f("ix_family_runs_job_id"), table_name="family_runs")
    op.drop_table("family_runs")
    op.drop_index(op.f("ix_families_created_at"), table_name="families")
    op.drop_index(op.f("ix_families_status"), table_name="families")
    op.drop_index(op.f("ix_families_family"), table_name="families")
    op.drop_table("families")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("result")
        batch.drop_column("start")
