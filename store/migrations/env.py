"""Alembic environment for the store's migrations.

The connection comes from, in order: `config.attributes["connection"]`,
`config.attributes["engine"]` (see `store.db.init_db`), the `sqlalchemy.url` option, or the
CMRT settings. Migrations of several processes starting at once are serialised (PostgreSQL
advisory lock; SQLite's `BEGIN IMMEDIATE` from `store.db.make_engine`).
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import text

from store.db import make_engine
from store.models import Base

config = context.config
target_metadata = Base.metadata
MIGRATION_LOCK_KEY = 727_117_001  # arbitrary constant for pg_advisory_xact_lock


def _run(connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )
    with context.begin_transaction():
        if connection.dialect.name == "postgresql":
            connection.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": MIGRATION_LOCK_KEY})
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    engine = config.attributes.get("engine")
    owned = engine is None
    if owned:
        url = config.get_main_option("sqlalchemy.url")
        if not url:
            from cmrt.settings import get_settings

            url = get_settings().database_url
        engine = make_engine(url)
    try:
        with engine.connect() as connection:
            _run(connection)
            connection.commit()
    finally:
        if owned:
            engine.dispose()


def run_migrations_offline() -> None:
    context.configure(
        url=config.get_main_option("sqlalchemy.url"),
        target_metadata=target_metadata,
        literal_binds=True,
    )
    with context.begin_transaction():
        context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
