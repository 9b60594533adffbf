"""Fixtures of the worker unit tests: a migrated store on SQLite and on PostgreSQL (the same
server as the store contract suite, CMRT_TEST_POSTGRES_URL, one throw-away schema per test
session; skipped with the reason only when the server cannot be reached), and a synthetic
objective (tests/synthetic.py; fakes only here, never in the integration tests)."""

from __future__ import annotations

import os
import uuid

import pytest
from sqlalchemy import create_engine, delete, text
from sqlalchemy.engine import make_url

from store.db import init_db
from store.models import Base
from store.repository import SqlRepository

PG_URL = os.environ.get(
    "CMRT_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)


@pytest.fixture(scope="session")
def _pg_schema_url():
    admin = create_engine(PG_URL, connect_args={"connect_timeout": 3})
    try:
        with admin.connect() as c:
            c.execute(text("SELECT 1"))
    except Exception as err:  # noqa: BLE001 - any failure means "unreachable"
        admin.dispose()
        yield None, f"{type(err).__name__}: {str(err).splitlines()[0]}"
        return
    schema = f"cmrt_wtest_{os.getpid()}_{uuid.uuid4().hex[:8]}"
    with admin.begin() as c:
        c.execute(text(f'CREATE SCHEMA "{schema}"'))
    url = make_url(PG_URL).update_query_dict({"options": f"-csearch_path={schema}"})
    try:
        yield url.render_as_string(hide_password=False), None
    finally:
        with admin.begin() as c:
            c.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
        admin.dispose()


@pytest.fixture(scope="session",
                params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def _engine(request, tmp_path_factory, _pg_schema_url):
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path_factory.mktemp('wdb') / 'cmrt.db'}"
    else:
        url, error = _pg_schema_url
        if url is None:
            pytest.skip(f"PostgreSQL at {PG_URL} unreachable ({error})")
    engine = init_db(url)
    yield engine
    engine.dispose()


@pytest.fixture
def repo(_engine) -> SqlRepository:
    with _engine.begin() as c:
        for table in reversed(Base.metadata.sorted_tables):
            c.execute(delete(table))
    return SqlRepository(_engine)
