"""Library entries record which candidate won: the best searched CMRT or the flat spline.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-02
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("cmrts") as batch:
        batch.add_column(
            sa.Column("winner", sa.String(length=16), nullable=False, server_default="search")
        )


def downgrade() -> None:
    with op.batch_alter_table("cmrts") as batch:
        batch.drop_column("winner")
