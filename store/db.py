"""Engines, schema migration and sessions.

- `make_engine(url)`: an Engine ready for several processes writing at once. SQLite gets WAL,
  foreign keys, a busy timeout, and `BEGIN IMMEDIATE` for transactions (so two writers queue on
  the busy timeout instead of failing on a lock upgrade); the SQLite file's folder is created on
  demand. PostgreSQL gets TCP keepalives and a connect timeout (`PG_*`). After `os.fork()` the
  child drops the parent's pooled connections.
- `init_db(url_or_engine)`: create or upgrade the schema to the latest Alembic revision.
- `session_scope(engine)`: a Session committing on success, rolling back on error.

Create one engine per process (worker pool processes included) and share it between threads.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import URL, make_url
from sqlalchemy.orm import Session
from sqlalchemy.pool import StaticPool

MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
SQLITE_BUSY_TIMEOUT_MS = 30_000
#: libpq TCP keepalives on every PostgreSQL connection: a server or a network path that dies
#: silently (no FIN/RST) is noticed after IDLE + INTERVAL x COUNT seconds (60 s) instead of
#: the kernel's default two hours, so a worker's store call fails and is retried rather than
#: hanging on a dead socket; CONNECT_TIMEOUT bounds a connection attempt to an unreachable host.
PG_KEEPALIVE_IDLE_S = 30
PG_KEEPALIVE_INTERVAL_S = 10
PG_KEEPALIVE_COUNT = 3
PG_CONNECT_TIMEOUT_S = 10

#: Execution option: run this engine's SQLite transactions as `BEGIN` (deferred, read-only use)
#: instead of `BEGIN IMMEDIATE`.
READ_ONLY_OPTION = "cmrt_read_only"


def _is_memory(url: URL) -> bool:
    return url.database in (None, "", ":memory:") or "mode=memory" in str(url)


def make_engine(url: str | URL, **kwargs: Any) -> Engine:
    """Build an Engine for `url` (SQLite or PostgreSQL, e.g. `postgresql+psycopg://...`).

    Extra keyword arguments go to `sqlalchemy.create_engine`.
    """
    u = make_url(url)
    backend = u.get_backend_name()
    if backend == "sqlite":
        engine = _sqlite_engine(u, **kwargs)
    elif backend == "postgresql":
        kwargs.setdefault("pool_pre_ping", True)
        connect_args = {"keepalives": 1, "keepalives_idle": PG_KEEPALIVE_IDLE_S,
                        "keepalives_interval": PG_KEEPALIVE_INTERVAL_S,
                        "keepalives_count": PG_KEEPALIVE_COUNT,
                        "connect_timeout": PG_CONNECT_TIMEOUT_S,
                        **kwargs.pop("connect_args", {})}
        engine = create_engine(u, connect_args=connect_args, **kwargs)
    else:
        raise ValueError(f"unsupported database {backend!r}: use sqlite or postgresql")

    ref = weakref.ref(engine)

    def _after_fork() -> None:  # a forked child must not reuse the parent's connections
        e = ref()
        if e is not None:
            e.dispose(close=False)

    os.register_at_fork(after_in_child=_after_fork)
    return engine


def _sqlite_engine(u: URL, **kwargs: Any) -> Engine:
    connect_args = dict(kwargs.pop("connect_args", {}))
    connect_args.setdefault("timeout", SQLITE_BUSY_TIMEOUT_MS / 1000)
    memory = _is_memory(u)
    if memory:
        # One shared connection, else every connection would see its own empty database.
        connect_args.setdefault("check_same_thread", False)
        kwargs.setdefault("poolclass", StaticPool)
    else:
        Path(u.database).expanduser().parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(u, connect_args=connect_args, **kwargs)

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn: Any, _record: Any) -> None:
        # Let SQLAlchemy (below) emit BEGIN itself instead of the sqlite3 module's implicit one.
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        try:
            if not memory:
                cur.execute("PRAGMA journal_mode=WAL")
                cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        finally:
            cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Any) -> None:
        read_only = conn.get_execution_options().get(READ_ONLY_OPTION, False)
        conn.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")

    return engine


def alembic_config(engine_or_url: Engine | str | URL | None = None) -> Any:
    """A programmatic Alembic Config for the packaged migrations (no alembic.ini needed)."""
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    if isinstance(engine_or_url, Engine):
        cfg.attributes["engine"] = engine_or_url
    elif engine_or_url is not None:
        cfg.set_main_option(
            "sqlalchemy.url",
            make_url(engine_or_url).render_as_string(hide_password=False).replace("%", "%%"),
        )
    return cfg


def init_db(url_or_engine: str | URL | Engine | None = None) -> Engine:
    """Create or upgrade the schema to the newest migration (`alembic upgrade head`).

    Safe to call from several processes at once and on every start. With no argument the URL
    comes from `cmrt.settings.get_settings().database_url`. Returns the engine used.
    """
    from alembic import command

    if url_or_engine is None:
        from cmrt.settings import get_settings

        url_or_engine = get_settings().database_url
        assert url_or_engine is not None
    engine = (
        url_or_engine if isinstance(url_or_engine, Engine) else make_engine(url_or_engine)
    )
    command.upgrade(alembic_config(engine), "head")
    return engine


@contextmanager
def session_scope(engine: Engine, *, read_only: bool = False) -> Iterator[Session]:
    """A Session in one transaction: committed on success, rolled back on an exception."""
    bind = engine.execution_options(**{READ_ONLY_OPTION: True}) if read_only else engine
    with Session(bind, expire_on_commit=False) as session, session.begin():
        yield session
