"""The library keeps the simulated outcome of every CMRT it served with `verify`: one row per
(spec hash, CMRT parameters hash), so an identical query is answered without simulating.

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-06
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "cmrt_verifications",
        sa.Column("id", sa.String(length=36), nullable=False),
        sa.Column("family", sa.String(length=100), nullable=False),
        sa.Column("spec_hash", sa.String(length=64), nullable=False),
        sa.Column("params_hash", sa.String(length=64), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("members", sa.JSON(), nullable=False),
        sa.Column("outcome", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_cmrt_verifications")),
        sa.UniqueConstraint("spec_hash", "params_hash", name="uq_cmrt_verifications_key"),
    )
    op.create_index(op.f("ix_cmrt_verifications_family"), "cmrt_verifications", ["family"])


def downgrade() -> None:
    op.drop_index(op.f("ix_cmrt_verifications_family"), table_name="cmrt_verifications")
    op.drop_table("cmrt_verifications")
