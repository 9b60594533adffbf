"""A job's spec and a family's request are stored with the hash of their canonical text
(`cmrt.canonical`): the key a process caches the parsed spec under, so that it parses a spec at
most once. Rows written before are hashed here.

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-05
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from cmrt.canonical import document_hash

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None

TABLES = ("jobs", "families")


def upgrade() -> None:
    conn = op.get_bind()
    for table in TABLES:
        with op.batch_alter_table(table) as batch:
            batch.add_column(sa.Column("spec_hash", sa.String(length=64), nullable=True))
        t = sa.table(table, sa.column("id", sa.String()), sa.column("spec", sa.JSON()),
                     sa.column("spec_hash", sa.String()))
        for row_id, spec in conn.execute(sa.select(t.c.id, t.c.spec)).all():
            conn.execute(t.update().where(t.c.id == row_id)
                         .values(spec_hash=document_hash(spec or {})))
        with op.batch_alter_table(table) as batch:
            batch.alter_column("spec_hash", existing_type=sa.String(length=64), nullable=False)


def downgrade() -> None:
    for table in TABLES:
        with op.batch_alter_table(table) as batch:
            batch.drop_column("spec_hash")
