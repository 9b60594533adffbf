"""Migrations create exactly the models' schema, on both backends, and can be re-run."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
from collections.abc import Callable

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import Engine, inspect

from store.db import alembic_config, init_db, make_engine
from store.models import Base


def _diffs(engine: Engine) -> list:
    with engine.connect() as conn:
        ctx = MigrationContext.configure(conn, opts={"compare_type": True})
        return compare_metadata(ctx, Base.metadata)


def test_migrated_schema_equals_models(migrated: tuple[str, Engine]) -> None:
    _url, engine = migrated
    assert _diffs(engine) == []
    tables = set(inspect(engine).get_table_names())
    assert tables == set(Base.metadata.tables) | {"alembic_version"}


def test_init_db_is_idempotent_and_downgrade_works(
    backend: str, url_factory: Callable[[str], str]
) -> None:
    url = url_factory(backend)
    engine = init_db(url)
    try:
        init_db(engine)  # second run: nothing to do
        assert _diffs(engine) == []
        command.downgrade(alembic_config(engine), "base")
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
        init_db(engine)
        assert _diffs(engine) == []
    finally:
        engine.dispose()


def _init_in_child(url: str) -> None:
    init_db(url).dispose()


def test_concurrent_init_db_from_two_processes(
    backend: str, url_factory: Callable[[str], str]
) -> None:
    url = url_factory(backend)
    ctx = mp.get_context("fork")
    procs = [ctx.Process(target=_init_in_child, args=(url,)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    engine = make_engine(url)
    try:
        assert _diffs(engine) == []
    finally:
        engine.dispose()


def test_sqlite_engine_pragmas(tmp_path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path}/sub/dir/x.db")  # folder created on demand
    try:
        with engine.connect() as c:
            assert c.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
            assert c.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
            assert c.exec_driver_sql("PRAGMA busy_timeout").scalar() >= 1000
    finally:
        engine.dispose()


def test_unsupported_database_is_refused() -> None:
    with pytest.raises(ValueError, match="unsupported database"):
        make_engine("mysql://x@localhost/db")



@pytest.mark.postgres
def test_postgres_connections_carry_tcp_keepalives(pg_server):
    """A silently dead server or path is noticed in about a minute, not the kernel's 2 h: the
    socket of a pooled connection has keepalives on with the store's idle, interval, count."""
    import socket

    from store.db import PG_KEEPALIVE_COUNT, PG_KEEPALIVE_IDLE_S, PG_KEEPALIVE_INTERVAL_S
    if not pg_server.available():
        pytest.skip(f"PostgreSQL unreachable ({pg_server.error})")
    engine = make_engine(pg_server.new_url())
    try:
        with engine.connect() as c:
            fd = c.connection.dbapi_connection.pgconn.socket
            sock = socket.socket(fileno=os.dup(fd))
            try:
                got = [sock.getsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE) != 0,
                       *(sock.getsockopt(socket.IPPROTO_TCP, o) for o in (
                           socket.TCP_KEEPIDLE, socket.TCP_KEEPINTVL, socket.TCP_KEEPCNT))]
            finally:
                sock.close()
    finally:
        engine.dispose()
    assert got == [True, PG_KEEPALIVE_IDLE_S, PG_KEEPALIVE_INTERVAL_S, PG_KEEPALIVE_COUNT]


def test_spec_hash_migration_hashes_rows_written_before(
    backend: str, url_factory: Callable[[str], str]
) -> None:
    """Jobs and families stored before the spec hash existed get the hash of their canonical
    text, the one the boundary computes for a new row."""
    from datetime import UTC, datetime

    from sqlalchemy import text

    from cmrt.canonical import document_hash

    engine = make_engine(url_factory(backend))
    spec = {"name": "old", "clip": {"duration": 0.4, "preparation": 1.0}, "task": {"type": "x"}}
    try:
        command.upgrade(alembic_config(engine), "0003")
        now = datetime.now(UTC).replace(tzinfo=None)
        with engine.begin() as c:
            c.execute(text(
                "INSERT INTO jobs (id, name, family, task, spec, workers, status, created_at, "
                "evaluations, iterations, cancel_requested) VALUES ('j1', 'old', 'old', 'x', "
                ":spec, 1, 'queued', :now, 0, 0, false)"), {"spec": json.dumps(spec), "now": now})
            c.execute(text(
                "INSERT INTO families (id, family, param, spec, status, cancel_requested, "
                "created_at) VALUES ('f1', 'old', 'clip.duration', :spec, 'running', false, "
                ":now)"), {"spec": json.dumps({"spec": spec, "values": [0.4]}), "now": now})
        init_db(engine)
        assert _diffs(engine) == []
        with engine.connect() as c:
            assert c.execute(text("SELECT spec_hash FROM jobs")).scalar_one() == \
                document_hash(spec)
            assert c.execute(text("SELECT spec_hash FROM families")).scalar_one() == \
                document_hash({"spec": spec, "values": [0.4]})
    finally:
        engine.dispose()
