"""Initial schema: jobs, generations, evaluations, the CMRT library and PCA bases.

Revision ID: 0001
Revises:
Create Date: 2026-11-22
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def _ts(name: str, nullable: bool = False) -> sa.Column:
    return sa.Column(name, sa.DateTime(timezone=True), nullable=nullable)


def upgrade() -> None:
    # tables in an order where every foreign key names an existing table
    _create_bases()
    _create_jobs()
    _create_cmrts()
    _create_evaluations()
    _create_generations()
    _create_cmrt_parameters()


def _create_bases() -> None:
    """PCA bases of a family."""
    op.create_table(
        "bases",
        sa.Column("id", sa.String(length=36), nullable=False),
        sa.Column("family", sa.String(length=100), nullable=False),
        sa.Column("k", sa.Integer(), nullable=False),
        sa.Column("mean", sa.JSON(), nullable=False),
        sa.Column("components", sa.JSON(), nullable=False),
        sa.Column("variance_explained", sa.JSON(), nullable=False),
        sa.Column("members", sa.JSON(), nullable=False),
        sa.Column("box", sa.JSON(), nullable=True),
        _ts("created_at"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_bases")),
    )
    op.create_index(op.f("ix_bases_family"), "bases", ["family"])


def _create_jobs() -> None:
    """Optimisation jobs (a job may name the basis it searches in)."""
    op.create_table(
        "jobs",
        sa.Column("id", sa.String(length=36), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("family", sa.String(length=100), nullable=False),
        sa.Column("task", sa.String(length=32), nullable=False),
        sa.Column("spec", sa.JSON(), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=True),
        sa.Column("workers", sa.Integer(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("stop_rule", sa.String(length=64), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("basis_id", sa.String(length=36), nullable=True),
        _ts("created_at"),
        _ts("started_at", nullable=True),
        _ts("finished_at", nullable=True),
        sa.Column("best_objective", sa.Float(), nullable=True),
        sa.Column("best_params", sa.JSON(), nullable=True),
        sa.Column("evaluations", sa.Integer(), nullable=False),
        sa.Column("iterations", sa.Integer(), nullable=False),
        sa.Column("cancel_requested", sa.Boolean(), nullable=False),
        sa.Column("optimizer_state", sa.LargeBinary(), nullable=True),
        sa.Column("driver_owner", sa.String(length=200), nullable=True),
        _ts("lease_expires_at", nullable=True),
        _ts("heartbeat_at", nullable=True),
        sa.ForeignKeyConstraint(
            ["basis_id"], ["bases.id"], name=op.f("fk_jobs_basis_id_bases"), ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_jobs")),
    )
    op.create_index(op.f("ix_jobs_created_at"), "jobs", ["created_at"])
    op.create_index(op.f("ix_jobs_family"), "jobs", ["family"])
    op.create_index(op.f("ix_jobs_status"), "jobs", ["status"])


def _create_cmrts() -> None:
    """The library's CMRTs (each from the job that found it, if any)."""
    op.create_table(
        "cmrts",
        sa.Column("id", sa.String(length=36), nullable=False),
        sa.Column("family", sa.String(length=100), nullable=False),
        sa.Column("character", sa.JSON(), nullable=False),
        sa.Column("task_parameters", sa.JSON(), nullable=False),
        sa.Column("preparation", sa.Float(), nullable=False),
        sa.Column("duration", sa.Float(), nullable=False),
        sa.Column("decay", sa.Float(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("knots", sa.JSON(), nullable=False),
        sa.Column("values", sa.JSON(), nullable=False),
        sa.Column("curve", sa.JSON(), nullable=False),
        sa.Column("objective", sa.Float(), nullable=False),
        sa.Column("objective_without", sa.Float(), nullable=True),
        sa.Column("fell", sa.Boolean(), nullable=False),
        sa.Column("fell_without", sa.Boolean(), nullable=True),
        sa.Column("job_id", sa.String(length=36), nullable=True),
        sa.Column("spec", sa.JSON(), nullable=True),
        _ts("created_at"),
        sa.ForeignKeyConstraint(
            ["job_id"], ["jobs.id"], name=op.f("fk_cmrts_job_id_jobs"), ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_cmrts")),
    )
    op.create_index(op.f("ix_cmrts_family"), "cmrts", ["family"])
    op.create_index(op.f("ix_cmrts_job_id"), "cmrts", ["job_id"])


def _create_evaluations() -> None:
    """A job's candidates, one row per generation and index."""
    op.create_table(
        "evaluations",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("job_id", sa.String(length=36), nullable=False),
        sa.Column("generation", sa.Integer(), nullable=False),
        sa.Column("index", sa.Integer(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=True),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("objective", sa.Float(), nullable=True),
        sa.Column("fell", sa.Boolean(), nullable=True),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("cpu_seconds", sa.Float(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("details", sa.JSON(), nullable=True),
        _ts("created_at"),
        _ts("updated_at"),
        sa.ForeignKeyConstraint(
            ["job_id"], ["jobs.id"], name=op.f("fk_evaluations_job_id_jobs"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_evaluations")),
        sa.UniqueConstraint(
            "job_id", "generation", "index", name=op.f("uq_evaluations_job_id_generation_index")
        ),
    )


def _create_generations() -> None:
    """A job's generations (statistics and the optimizer's state)."""
    op.create_table(
        "generations",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("job_id", sa.String(length=36), nullable=False),
        sa.Column("iteration", sa.Integer(), nullable=False),
        sa.Column("best", sa.Float(), nullable=False),
        sa.Column("median", sa.Float(), nullable=False),
        sa.Column("worst", sa.Float(), nullable=False),
        sa.Column("sigma", sa.Float(), nullable=False),
        sa.Column("best_so_far", sa.Float(), nullable=False),
        sa.Column("evaluations", sa.Integer(), nullable=False),
        sa.Column("wall_time", sa.Float(), nullable=False),
        sa.Column("candidates", sa.JSON(), nullable=False),
        sa.Column("optimizer_state", sa.LargeBinary(), nullable=True),
        _ts("created_at"),
        sa.ForeignKeyConstraint(
            ["job_id"], ["jobs.id"], name=op.f("fk_generations_job_id_jobs"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_generations")),
        sa.UniqueConstraint("job_id", "iteration", name=op.f("uq_generations_job_id_iteration")),
    )


def _create_cmrt_parameters() -> None:
    """A library CMRT's task parameters, one row each (the nearness queries' index)."""
    op.create_table(
        "cmrt_parameters",
        sa.Column("cmrt_id", sa.String(length=36), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(
            ["cmrt_id"],
            ["cmrts.id"],
            name=op.f("fk_cmrt_parameters_cmrt_id_cmrts"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("cmrt_id", "name", name=op.f("pk_cmrt_parameters")),
    )
    op.create_index("ix_cmrt_parameters_name_value", "cmrt_parameters", ["name", "value"])


def downgrade() -> None:
    op.drop_index("ix_cmrt_parameters_name_value", table_name="cmrt_parameters")
    op.drop_table("cmrt_parameters")
    op.drop_table("generations")
    op.drop_table("evaluations")
    op.drop_index(op.f("ix_cmrts_job_id"), table_name="cmrts")
    op.drop_index(op.f("ix_cmrts_family"), table_name="cmrts")
    op.drop_table("cmrts")
    op.drop_index(op.f("ix_jobs_status"), table_name="jobs")
    op.drop_index(op.f("ix_jobs_family"), table_name="jobs")
    op.drop_index(op.f("ix_jobs_created_at"), table_name="jobs")
    op.drop_table("jobs")
    op.drop_index(op.f("ix_bases_family"), table_name="bases")
    op.drop_table("bases")
