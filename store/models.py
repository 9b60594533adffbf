"""SQLAlchemy 2.0 models. Portable types only: the same schema runs on SQLite and PostgreSQL.

Each model is one table's row and is named `<thing>Row` (`JobRow`, `CmrtRow`, ...): the names
`Job`, `Basis`, `Evaluation` belong to what the rest of the product handles (the client's job,
the PCA basis, a simulation's evaluation), and the store hands out `store.records` only.

The schema is created by the Alembic migrations in `store/migrations` (see `store.db.init_db`);
`Base.metadata` must stay identical to what they create (a test compares the two).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.engine import Dialect
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class UTCDateTime(TypeDecorator[datetime]):
    """A timestamp stored as UTC and always returned timezone-aware (UTC).

    PostgreSQL stores `timestamp with time zone`; SQLite has no time zones, so values are
    stored as naive UTC and given back their UTC zone on load.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to the store; use timezone-aware UTC")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {datetime: UTCDateTime(), dict[str, Any]: JSON, Any: JSON}


class JobRow(Base):
    """One optimisation job: its spec, state machine, progress and the latest optimizer state."""

    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    name: Mapped[str] = mapped_column(String(100))
    family: Mapped[str] = mapped_column(String(100), index=True)
    task: Mapped[str] = mapped_column(String(32))
    spec: Mapped[dict[str, Any]] = mapped_column(JSON)
    #: SHA-256 of the spec's canonical text (cmrt.canonical): the key processes cache it under.
    spec_hash: Mapped[str] = mapped_column(String(64))
    seed: Mapped[int | None] = mapped_column(Integer)
    workers: Mapped[int] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16), index=True)
    stop_rule: Mapped[str | None] = mapped_column(String(64))
    error: Mapped[str | None] = mapped_column(Text)
    basis_id: Mapped[str | None] = mapped_column(
        String(36), ForeignKey("bases.id", ondelete="SET NULL")
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    best_objective: Mapped[float | None] = mapped_column(Float)
    best_params: Mapped[Any | None] = mapped_column(JSON)
    evaluations: Mapped[int] = mapped_column(Integer)
    iterations: Mapped[int] = mapped_column(Integer)
    cancel_requested: Mapped[bool] = mapped_column(Boolean)
    optimizer_state: Mapped[bytes | None] = mapped_column(LargeBinary, deferred=True)
    driver_owner: Mapped[str | None] = mapped_column(String(200))
    lease_expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    heartbeat_at: Mapped[datetime | None] = mapped_column(UTCDateTime())
    #: Where the search started: {"from": what, "x0": full params} (None: the flat spline).
    start: Mapped[Any | None] = mapped_column(JSON)
    #: The finished job's result document (optim.result.OptimizationResult.to_dict()).
    result: Mapped[Any | None] = mapped_column(JSON, deferred=True)


class FamilyRow(Base):
    """A family of CMRTs along one task parameter: its request and, once finished, its report;
    its runs are ordinary jobs (`FamilyRunRow`)."""

    __tablename__ = "families"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    #: The library family its members land in (the base spec's family).
    family: Mapped[str] = mapped_column(String(100), index=True)
    param: Mapped[str] = mapped_column(String(200))
    #: The family request (optim.family.spec.FamilySpec, JSON form).
    spec: Mapped[Any] = mapped_column(JSON)
    #: SHA-256 of the request's canonical text (cmrt.canonical).
    spec_hash: Mapped[str] = mapped_column(String(64))
    status: Mapped[str] = mapped_column(String(16), index=True)
    error: Mapped[str | None] = mapped_column(Text)
    cancel_requested: Mapped[bool] = mapped_column(Boolean)
    #: Outcomes of the interpolated CMRTs at the members' values: [[value, outcome], ...].
    probes: Mapped[Any | None] = mapped_column(JSON, deferred=True)
    #: optim.family.report.family_report, once every run is finished.
    report: Mapped[Any | None] = mapped_column(JSON, deferred=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), index=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime())


class FamilyRunRow(Base):
    """One run of a family's plan and the job that runs it (one job per run: the primary key
    makes creating it idempotent when several drivers advance the family)."""

    __tablename__ = "family_runs"

    family_id: Mapped[str] = mapped_column(
        String(36), ForeignKey("families.id", ondelete="CASCADE"), primary_key=True
    )
    run_id: Mapped[str] = mapped_column(String(100), primary_key=True)
    job_id: Mapped[str] = mapped_column(
        String(36), ForeignKey("jobs.id", ondelete="CASCADE"), index=True
    )


class GenerationRow(Base):
    """One CMA-ES generation of a job: its figures and the optimizer state after telling it."""

    __tablename__ = "generations"
    __table_args__ = (UniqueConstraint("job_id", "iteration"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    job_id: Mapped[str] = mapped_column(String(36), ForeignKey("jobs.id", ondelete="CASCADE"))
    iteration: Mapped[int] = mapped_column(Integer)
    best: Mapped[float] = mapped_column(Float)
    median: Mapped[float] = mapped_column(Float)
    worst: Mapped[float] = mapped_column(Float)
    sigma: Mapped[float] = mapped_column(Float)
    best_so_far: Mapped[float] = mapped_column(Float)
    evaluations: Mapped[int] = mapped_column(Integer)
    wall_time: Mapped[float] = mapped_column(Float)
    candidates: Mapped[Any] = mapped_column(JSON)
    optimizer_state: Mapped[bytes | None] = mapped_column(LargeBinary, deferred=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())


class EvaluationRow(Base):
    """One candidate of one generation: its parameters, result and attempt count."""

    __tablename__ = "evaluations"
    __table_args__ = (UniqueConstraint("job_id", "generation", "index"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    job_id: Mapped[str] = mapped_column(String(36), ForeignKey("jobs.id", ondelete="CASCADE"))
    generation: Mapped[int] = mapped_column(Integer)
    index: Mapped[int] = mapped_column(Integer)
    params: Mapped[Any | None] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(16))
    objective: Mapped[float | None] = mapped_column(Float)
    fell: Mapped[bool | None] = mapped_column(Boolean)
    attempts: Mapped[int] = mapped_column(Integer)
    cpu_seconds: Mapped[float | None] = mapped_column(Float)
    error: Mapped[str | None] = mapped_column(Text)
    details: Mapped[Any | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime())
    #: The numeric fingerprint of the process that evaluated it (sim.fingerprint), if known.
    fingerprint: Mapped[str | None] = mapped_column(String(64))


class CmrtRow(Base):
    """A library entry: an optimised CMRT for one task of a family, at given task parameters."""

    __tablename__ = "cmrts"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    family: Mapped[str] = mapped_column(String(100), index=True)
    character: Mapped[Any] = mapped_column(JSON)
    task_parameters: Mapped[Any] = mapped_column(JSON)
    preparation: Mapped[float] = mapped_column(Float)
    duration: Mapped[float] = mapped_column(Float)
    decay: Mapped[float] = mapped_column(Float)
    params: Mapped[Any] = mapped_column(JSON)
    knots: Mapped[Any] = mapped_column(JSON)
    values: Mapped[Any] = mapped_column(JSON)
    curve: Mapped[Any] = mapped_column(JSON)
    objective: Mapped[float] = mapped_column(Float)
    objective_without: Mapped[float | None] = mapped_column(Float)
    fell: Mapped[bool] = mapped_column(Boolean)
    fell_without: Mapped[bool | None] = mapped_column(Boolean)
    #: "search" (the best candidate CMA-ES found) or "flat" (the flat spline was better).
    winner: Mapped[str] = mapped_column(String(16), server_default="search")
    job_id: Mapped[str | None] = mapped_column(
        String(36), ForeignKey("jobs.id", ondelete="SET NULL"), index=True
    )
    spec: Mapped[Any | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())


class CmrtParameterRow(Base):
    """One task parameter of a library CMRT, as a row so any name is queryable and indexed."""

    __tablename__ = "cmrt_parameters"
    __table_args__ = (Index("ix_cmrt_parameters_name_value", "name", "value"),)

    cmrt_id: Mapped[str] = mapped_column(
        String(36), ForeignKey("cmrts.id", ondelete="CASCADE"), primary_key=True
    )
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[float] = mapped_column(Float)


class BasisRow(Base):
    """A PCA basis of a family's library CMRTs (reduced-space re-optimisation)."""

    __tablename__ = "bases"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    family: Mapped[str] = mapped_column(String(100), index=True)
    k: Mapped[int] = mapped_column(Integer)
    mean: Mapped[Any] = mapped_column(JSON)
    components: Mapped[Any] = mapped_column(JSON)
    variance_explained: Mapped[Any] = mapped_column(JSON)
    members: Mapped[Any] = mapped_column(JSON)
    box: Mapped[Any | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())


class CmrtVerificationRow(Base):
    """The simulated outcome of a CMRT the library served (an interpolation, or a member at a
    task it was not optimised for): one row per (spec, CMRT parameters), so that the next
    identical query is answered without simulating."""

    __tablename__ = "cmrt_verifications"
    __table_args__ = (
        UniqueConstraint("spec_hash", "params_hash", name="uq_cmrt_verifications_key"),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    family: Mapped[str] = mapped_column(String(100), index=True)
    spec_hash: Mapped[str] = mapped_column(String(64))
    params_hash: Mapped[str] = mapped_column(String(64))
    #: "member", "interpolated" or "refined": what the simulated CMRT was.
    source: Mapped[str] = mapped_column(String(16))
    #: Ids of the library CMRTs it was built from.
    members: Mapped[Any] = mapped_column(JSON)
    #: objective, fell, fall_direction, task_success, status, error, cpu_seconds.
    outcome: Mapped[Any] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())



class CharacterRow(Base):
    """A user's character definition kept by name (POST /characters): specs name it as their
    `character.model` and get the definition inlined when they are submitted."""

    __tablename__ = "characters"
    __table_args__ = (UniqueConstraint("name", name="uq_characters_name"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    name: Mapped[str] = mapped_column(String(64))
    definition: Mapped[Any] = mapped_column(JSON)
    #: SHA-256 of the definition's canonical text (cmrt.canonical).
    definition_hash: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime())
