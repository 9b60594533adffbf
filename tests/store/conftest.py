"""Fixtures of the store's contract suite: every test using `repo` runs on SQLite and on
PostgreSQL.

PostgreSQL: `CMRT_TEST_POSTGRES_URL` (default postgresql+psycopg://postgres@127.0.0.1:5432/test);
each test session works in its own schema, dropped at the end. Tests are skipped (with the
reason) only when the server cannot be reached.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, delete, text
from sqlalchemy.engine import make_url

from store.db import init_db
from store.models import Base
from store.repository import SqlRepository

PG_URL = os.environ.get(
    "CMRT_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
BACKENDS = ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)]


class FakeClock:
    """Wall clock plus an offset that tests can advance (lease expiry without sleeping)."""

    def __init__(self) -> None:
        self.offset = timedelta()

    def __call__(self) -> datetime:
        return datetime.now(UTC) + self.offset

    def advance(self, seconds: float) -> None:
        self.offset += timedelta(seconds=seconds)


class PgServer:
    """Creates throw-away schemas on the test server and drops them at the end."""

    def __init__(self) -> None:
        self.admin: Engine | None = None
        self.error: str | None = None
        self.schemas: list[str] = []

    def available(self) -> bool:
        if self.admin is None and self.error is None:
            engine = create_engine(PG_URL, connect_args={"connect_timeout": 3})
            try:
                with engine.connect() as c:
                    c.execute(text("SELECT 1"))
                self.admin = engine
            except Exception as err:  # noqa: BLE001 - any failure means "unreachable"
                engine.dispose()
                self.error = f"{type(err).__name__}: {str(err).splitlines()[0]}"
        return self.admin is not None

    def new_url(self) -> str:
        assert self.admin is not None
        schema = f"cmrt_test_{os.getpid()}_{uuid.uuid4().hex[:8]}"
        with self.admin.begin() as c:
            c.execute(text(f'CREATE SCHEMA "{schema}"'))
        self.schemas.append(schema)
        url = make_url(PG_URL).update_query_dict({"options": f"-csearch_path={schema}"})
        return url.render_as_string(hide_password=False)

    def close(self) -> None:
        if self.admin is None:
            return
        with self.admin.begin() as c:
            for schema in self.schemas:
                c.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
        self.admin.dispose()


@pytest.fixture(scope="session")
def pg_server() -> Iterator[PgServer]:
    server = PgServer()
    yield server
    server.close()


@pytest.fixture(scope="session")
def url_factory(
    pg_server: PgServer, tmp_path_factory: pytest.TempPathFactory
) -> Callable[[str], str]:
    """backend -> URL of a fresh, empty database (SQLite file or PostgreSQL schema)."""

    def make(backend: str) -> str:
        if backend == "sqlite":
            path: Path = tmp_path_factory.mktemp("db") / "cmrt.db"
            return f"sqlite:///{path}"
        if not pg_server.available():
            pytest.skip(f"PostgreSQL at {PG_URL} unreachable ({pg_server.error})")
        return pg_server.new_url()

    return make


@pytest.fixture(scope="session", params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture(scope="session")
def migrated(backend: str, url_factory: Callable[[str], str]) -> Iterator[tuple[str, Engine]]:
    """(url, engine) of a database migrated to head, shared by the session's tests."""
    url = url_factory(backend)
    engine = init_db(url)
    yield url, engine
    engine.dispose()


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def db(migrated: tuple[str, Engine]) -> tuple[str, Engine]:
    """The migrated database, emptied before the test."""
    url, engine = migrated
    with engine.begin() as c:
        for table in reversed(Base.metadata.sorted_tables):
            c.execute(delete(table))
    return url, engine


@pytest.fixture
def repo(db: tuple[str, Engine], clock: FakeClock) -> SqlRepository:
    return SqlRepository(db[1], clock=clock)
