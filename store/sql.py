"""The SQL side shared by the repository's parts: `SqlBase` (engine, clock, transactions, row
locks), value checks for what is stored, and ORM row -> record conversions (each record's field
list is the record class's: `store.records`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import fields
from datetime import UTC, datetime
from functools import cache
from typing import Any, TypeVar

from sqlalchemy import Connection, Engine, select
from sqlalchemy.orm import Session

from store.db import READ_ONLY_OPTION, session_scope
from store.errors import NotFound
from store.models import GenerationRow, JobRow
from store.records import GenerationRecord, JobRecord, JobStart

Clock = Callable[[], datetime]
R = TypeVar("R")


def utcnow() -> datetime:
    return datetime.now(UTC)


def _json(value: Any, what: str) -> Any:
    """Plain JSON data: numpy arrays/scalars become lists/floats; non-finite floats refused."""
    if value is None or isinstance(value, (str, bool, int)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{what}: non-finite number {value!r} cannot be stored as JSON")
        return value
    if hasattr(value, "tolist"):  # numpy array or scalar, without importing numpy
        return _json(value.tolist(), what)
    if isinstance(value, Mapping):
        return {str(k): _json(v, what) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v, what) for v in value]
    raise ValueError(f"{what}: {type(value).__name__} is not JSON data")


def _num(value: Any, what: str, *, allow_inf: bool = True) -> float:
    x = float(value)
    if math.isnan(x) or (not allow_inf and math.isinf(x)):
        raise ValueError(f"{what}: {x!r} cannot be stored")
    return x


def _opt_num(value: Any, what: str) -> float | None:
    return None if value is None else _num(value, what)


@cache
def field_names(cls: type) -> tuple[str, ...]:
    """A dataclass's field names, in order."""
    return tuple(f.name for f in fields(cls))


def row_record(cls: type[R], row: Any, **given: Any) -> R:
    """A `store.records` record from an ORM row: each field is the row's attribute of the same
    name, but for those `given` (converted, or not the row's)."""
    return cls(**{n: getattr(row, n) for n in field_names(cls) if n not in given}, **given)


def _job_record(j: JobRow) -> JobRecord:
    return row_record(JobRecord, j, cancel_requested=bool(j.cancel_requested),
                      start=None if j.start is None else JobStart.from_json(j.start))


def _generation_record(g: GenerationRow, with_state: bool) -> GenerationRecord:
    return row_record(GenerationRecord, g,
                      optimizer_state=g.optimizer_state if with_state else None)


def _exact_eps(v: float) -> float:
    return 1e-9 * max(1.0, abs(v))


# ---- the workers' per-candidate statements, built once (see SqlRepository) ---------------

class SqlBase:
    """Engine, clock and transactions of `SqlRepository` (see its docstring). `clock` returns
    the current aware UTC time (tests inject one to expire leases)."""

    def __init__(self, engine: Engine, *, clock: Clock = utcnow) -> None:
        self.engine = engine
        self._clock = clock
        self._postgres = engine.dialect.name == "postgresql"
        self._read_engine = engine.execution_options(**{READ_ONLY_OPTION: True})

    # ---- helpers ------------------------------------------------------------------------
    def _write(self) -> Any:
        return session_scope(self.engine)

    @contextmanager
    def _evaluation_write(self) -> Iterator[Connection]:
        """A Core connection for the per-candidate statements: PostgreSQL in autocommit mode
        (each statement is its own transaction; the writes commit asynchronously by
        `_ASYNC_COMMIT`), SQLite in one write transaction (BEGIN IMMEDIATE)."""
        if self._postgres:
            with self.engine.connect() as conn:
                yield conn.execution_options(isolation_level="AUTOCOMMIT")
        else:
            with self.engine.begin() as conn:
                yield conn

    def _read(self) -> Any:
        return session_scope(self.engine, read_only=True)

    def _read_core(self) -> Any:
        """A Core connection in one read-only transaction (no ORM session: the hot reads)."""
        return self._read_engine.begin()

    @contextmanager
    def _read_statement(self) -> Iterator[Connection]:
        """A Core connection for one read statement: PostgreSQL in autocommit mode (the
        statement is its own consistent snapshot; no BEGIN and COMMIT round trips), SQLite in
        one read transaction (`_read_core`). The driver's reads of every generation."""
        if self._postgres:
            with self.engine.connect() as conn:
                yield conn.execution_options(isolation_level="AUTOCOMMIT")
        else:
            with self._read_core() as conn:
                yield conn

    @staticmethod
    def _lock_job(s: Session, job_id: str) -> JobRow:
        """Load and lock the job row (PostgreSQL: FOR NO KEY UPDATE; SQLite: the write
        transaction already excludes other writers)."""
        job = s.scalars(
            select(JobRow).where(JobRow.id == job_id).with_for_update(key_share=True)
        ).one_or_none()
        if job is None:
            raise NotFound(f"job {job_id!a} not found")
        return job

    @staticmethod
    def _lock_job_columns(s: Session | Connection, job_id: str, *columns: Any) -> Any:
        """Lock the job row as `_lock_job` does and read only `columns` of it (a Core row:
        no spec, start or best parameters decoded)."""
        row = s.execute(
            select(*columns).where(JobRow.__table__.c.id == job_id)
            .with_for_update(key_share=True)
        ).first()
        if row is None:
            raise NotFound(f"job {job_id!a} not found")
        return row

    @staticmethod
    def _require_job(s: Session, job_id: str) -> None:
        if s.scalar(select(JobRow.id).where(JobRow.id == job_id)) is None:
            raise NotFound(f"job {job_id!a} not found")

