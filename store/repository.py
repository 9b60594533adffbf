"""The repository: the only way the rest of the service reads and writes persistent state.

`Repository` states the contract (docstrings); `SqlRepository(engine)` implements it with
SQLAlchemy on SQLite (embedded default) and PostgreSQL (deployed). Every method is one
transaction; methods return frozen records from `store.records`, never ORM objects, and raise
the errors of `store.errors`. Several processes (the driver, local pool workers, Celery workers,
the HTTP service) may use the same database at once: every write that others race on is atomic.

Typical job flow (see design.md, "Jobs"):

1. service: `create_job(...)` -> queued.
2. driver: `acquire_driver_lease(job, me, ttl)`; `set_job_status(job, "running")`; keeps the
   lease with `renew_driver_lease` and gives it up when the lease is lost.
3. driver, each generation g: ask candidates (from `latest_generation(job).optimizer_state`, or
   a fresh optimizer for g = 0); `put_pending_evaluations(job, g, candidates)`; dispatch.
4. worker, per candidate: `c = claim_evaluation(job, g, i)`; if `c.status != "pending"` or
   `c.job_terminal` skip; if `c.attempts > max_attempts` -> `fail_evaluation(...)`; else
   evaluate `c.params` and `store_result(...)` (first result wins). The driver polls
   `evaluation_counts(job, g)` until every evaluation is resolved. (`start_attempt` and
   `record_evaluation` are the same steps in finer pieces; `record_evaluation`'s outcome also
   tells its caller whether it was the one write that resolved the generation's last
   evaluation: `changed and counts.resolved == popsize`.)
5. closing a generation: tell the optimizer the objectives of `evaluations(job, g)` and
   `record_generation(job, g, ...)` before asking g + 1 (idempotent: if another process closed
   it first, continue from the stored record's optimizer_state).
6. driver: `set_job_status(job, "converged" | "stopped" | "failed" | "cancelled", ...)`,
   checking `get_job(job).cancel_requested` between generations; `add_cmrt(...)` for results.
"""

from __future__ import annotations

import abc
import math
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import Connection, Engine, bindparam, case, func, or_, select, text, update
from sqlalchemy.orm import Session, undefer

from store.db import session_scope
from store.errors import Conflict, InvalidTransition, NotFound
from store.models import Basis, Cmrt, CmrtParameter, Evaluation, Generation, Job
from store.records import (
    CANCELLED,
    DONE,
    EVAL_FAILED,
    JOB_STATUSES,
    PENDING,
    QUEUED,
    RUNNING,
    TERMINAL_STATUSES,
    TRANSITIONS,
    BasisRecord,
    CmrtRecord,
    EvaluationClaim,
    EvaluationOutcome,
    EvaluationRecord,
    GenerationCounts,
    GenerationRecord,
    JobRecord,
)

Clock = Callable[[], datetime]


def utcnow() -> datetime:
    return datetime.now(UTC)


class Repository(abc.ABC):
    """Persistent state of jobs, generations, evaluations, the CMRT library and PCA bases."""

    # ---- jobs ---------------------------------------------------------------------------
    @abc.abstractmethod
    def create_job(
        self,
        spec: Mapping[str, Any],
        *,
        name: str,
        family: str,
        task: str,
        seed: int | None = None,
        workers: int = 1,
        basis_id: str | None = None,
    ) -> JobRecord:
        """Store a new job in status `queued` and return it (a fresh uuid4 string id).

        `spec` is the JSON form of the TaskSpec (`spec.model_dump(mode="json")`).
        Raises Conflict if `basis_id` names no stored basis.
        """

    @abc.abstractmethod
    def get_job(self, job_id: str) -> JobRecord:
        """The job; raises NotFound."""

    @abc.abstractmethod
    def list_jobs(
        self,
        *,
        status: str | Iterable[str] | None = None,
        family: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[JobRecord], int]:
        """One page of jobs, newest first, and the total number matching the filters."""

    @abc.abstractmethod
    def set_job_status(
        self,
        job_id: str,
        status: str,
        *,
        stop_rule: str | None = None,
        error: str | None = None,
    ) -> JobRecord:
        """Move the job to `status` along `store.records.TRANSITIONS`; return the new record.

        Sets `started_at` on entering `running` and `finished_at` on entering a terminal
        state (which also releases the driver lease); `stop_rule` and `error` are stored when
        given. Setting the status the job already has is a no-op returning the record.
        Atomic compare-and-set: of two racing changes from the same state only one wins, the
        other raises InvalidTransition. Raises NotFound, InvalidTransition, ValueError for an
        unknown status.
        """

    @abc.abstractmethod
    def request_cancel(self, job_id: str) -> JobRecord:
        """Ask for cancellation: a queued job is cancelled at once; a running job gets
        `cancel_requested` set and its driver cancels it between generations; a finished job is
        left unchanged. Returns the record. Raises NotFound."""

    @abc.abstractmethod
    def get_optimizer_state(self, job_id: str) -> bytes | None:
        """The pickled optimizer of the latest recorded generation (None before the first).
        Raises NotFound."""

    # ---- generations --------------------------------------------------------------------
    @abc.abstractmethod
    def record_generation(
        self,
        job_id: str,
        iteration: int,
        *,
        best: float,
        median: float,
        worst: float,
        sigma: float,
        best_so_far: float,
        evaluations: int,
        wall_time: float,
        candidates: Sequence[Sequence[float]],
        optimizer_state: bytes | None,
        best_params: Sequence[float] | None = None,
    ) -> GenerationRecord:
        """Store generation `iteration` (0-based) of the job once.

        In the same transaction the job's `iterations`, `evaluations` and optimizer state
        become this generation's (if it is the newest), and `best_objective` / `best_params`
        are updated when `best` improves on them. `evaluations` is the job's cumulative count
        after this generation. Idempotent: if (job, iteration) is already stored, nothing
        changes and the stored record is returned (continue from its optimizer_state).
        Raises NotFound; ValueError for NaN figures.
        """

    @abc.abstractmethod
    def latest_generation(self, job_id: str) -> GenerationRecord | None:
        """The newest generation with its optimizer_state, or None. Raises NotFound."""

    @abc.abstractmethod
    def generations(
        self, job_id: str, *, after: int = -1, with_state: bool = False
    ) -> list[GenerationRecord]:
        """Generations with iteration > `after`, oldest first; optimizer_state only if
        `with_state`. Raises NotFound."""

    # ---- evaluations --------------------------------------------------------------------
    @abc.abstractmethod
    def put_pending_evaluations(
        self, job_id: str, generation: int, params_list: Sequence[Sequence[float]]
    ) -> int:
        """Create pending evaluations (index = position in `params_list`) for a generation.

        Idempotent: existing (job, generation, index) rows are left as they are. Returns the
        number of rows created. Raises NotFound.
        """

    @abc.abstractmethod
    def start_attempt(self, job_id: str, generation: int, index: int) -> EvaluationRecord:
        """Count one more attempt at a pending evaluation (atomic increment) and return it.

        If the evaluation is no longer pending (done or failed) nothing is counted and the
        record is returned as it is: the caller skips the work. The caller compares
        `attempts` with its limit and calls `fail_evaluation` when it is exceeded (so a
        candidate that kills its worker every time fails instead of looping). Raises NotFound
        (also when `put_pending_evaluations` was not called for the key).
        """

    @abc.abstractmethod
    def record_evaluation(
        self,
        job_id: str,
        generation: int,
        index: int,
        *,
        objective: float | None,
        fell: bool | None,
        cpu_seconds: float | None,
        error: str | None = None,
        details: Mapping[str, Any] | None = None,
        params: Sequence[float] | None = None,
    ) -> EvaluationOutcome:
        """Store an evaluation result: status `done`, or `failed` when `error` is given.

        Idempotent upsert keyed by (job, generation, index): the first result wins, a repeated
        write changes nothing and returns `changed=False`. Writes for one job are serialised,
        so `outcome.counts` are exact: exactly one write per generation has `changed` and
        `counts.resolved` equal to the population. A missing row is created (attempts 1).
        Raises NotFound for an unknown job; ValueError for a NaN objective.
        """

    @abc.abstractmethod
    def claim_evaluation(self, job_id: str, generation: int, index: int) -> EvaluationClaim:
        """A worker's start on one candidate, in one atomic step: count one more attempt if
        the evaluation is pending and return its status, attempts and params together with
        the job's status (`EvaluationClaim`).

        Same counting rules as `start_attempt`: an evaluation no longer pending (done or
        failed) is returned as it is with nothing counted (the caller skips the work); the
        caller compares `attempts` with its limit and calls `fail_evaluation` when it is
        exceeded, and skips the work when `job_terminal`. The attempt is visible to every
        other process as soon as this returns (a worker killed right after loses nothing).
        Durability on PostgreSQL: committed asynchronously (see `SqlRepository`): only a crash
        of the database server itself may forget the last fraction of a second of attempts.
        Raises NotFound when the evaluation does not exist (unknown job included).
        """

    @abc.abstractmethod
    def store_result(
        self,
        job_id: str,
        generation: int,
        index: int,
        *,
        objective: float | None,
        fell: bool | None,
        cpu_seconds: float | None,
        error: str | None = None,
        details: Mapping[str, Any] | None = None,
    ) -> bool:
        """Store a worker's result of an existing evaluation: `record_evaluation` without the
        generation counts, for callers that do not need them (the driver polls
        `evaluation_counts` itself).

        Status `done`, or `failed` when `error` is given. First result wins, atomically: only
        a pending evaluation is changed, and True is returned only by the write that moved
        it out of `pending`; a repeated or late write changes nothing and returns False.
        `params` are kept, `attempts` too (raised to 1 if no attempt was counted). Unlike
        `record_evaluation` it neither serialises on the job nor creates a missing row.
        The result is visible to every other process as soon as this returns. Durability on
        PostgreSQL: committed asynchronously (see `SqlRepository`): a crash of the database
        server itself may turn the last fraction of a second of results back to pending
        (they are evaluated again), never one that a later commit depended on.
        Raises NotFound when the evaluation does not exist; ValueError for a NaN objective or
        a missing objective without `error`.
        """

    def fail_evaluation(
        self, job_id: str, generation: int, index: int, error: str
    ) -> EvaluationOutcome:
        """Mark the evaluation failed (e.g. attempts exhausted); same rules as
        `record_evaluation`."""
        return self.record_evaluation(
            job_id, generation, index, objective=None, fell=None, cpu_seconds=None, error=error
        )

    @abc.abstractmethod
    def get_evaluation(self, job_id: str, generation: int, index: int) -> EvaluationRecord:
        """One evaluation; raises NotFound."""

    @abc.abstractmethod
    def evaluations(self, job_id: str, generation: int) -> list[EvaluationRecord]:
        """The generation's evaluations in index order (empty if none). Raises NotFound for
        an unknown job."""

    @abc.abstractmethod
    def evaluation_counts(self, job_id: str, generation: int) -> GenerationCounts:
        """Pending / done / failed counts of a generation."""

    def count_done(self, job_id: str, generation: int) -> int:
        """Number of `done` evaluations of a generation."""
        return self.evaluation_counts(job_id, generation).done

    # ---- driver lease -------------------------------------------------------------------
    @abc.abstractmethod
    def acquire_driver_lease(self, job_id: str, owner: str, ttl_s: float) -> bool:
        """Become the job's one driver for `ttl_s` seconds; True on success.

        Succeeds if nobody holds the lease, `owner` already holds it (then it is renewed), or
        the holder's lease has expired (takeover of a dead driver). Fails for a finished job.
        Atomic: of concurrent callers at most one succeeds. Raises NotFound.
        """

    @abc.abstractmethod
    def renew_driver_lease(self, job_id: str, owner: str, ttl_s: float) -> bool:
        """Extend `owner`'s lease (and heartbeat); False if another owner took it over."""

    @abc.abstractmethod
    def release_driver_lease(self, job_id: str, owner: str) -> None:
        """Give up the lease if `owner` holds it; otherwise do nothing."""

    @abc.abstractmethod
    def orphaned_jobs(self, limit: int = 100) -> list[JobRecord]:
        """Queued or running jobs without a live lease (never driven, or driver dead),
        oldest first: what a (re)started driver should pick up."""

    # ---- CMRT library -------------------------------------------------------------------
    @abc.abstractmethod
    def add_cmrt(
        self,
        *,
        family: str,
        character: Mapping[str, Any],
        task_parameters: Mapping[str, float],
        preparation: float,
        duration: float,
        decay: float,
        params: Sequence[float],
        knots: Sequence[float],
        values: Sequence[Any],
        curve: Any,
        objective: float,
        objective_without: float | None = None,
        fell: bool = False,
        fell_without: bool | None = None,
        job_id: str | None = None,
        spec: Mapping[str, Any] | None = None,
    ) -> str:
        """Add a library CMRT and return its id. Every task parameter becomes queryable by
        name (`find_cmrts`). Raises Conflict if `job_id` names no job; ValueError for
        non-finite task parameters or objective."""

    @abc.abstractmethod
    def get_cmrt(self, cmrt_id: str) -> CmrtRecord:
        """The CMRT; raises NotFound."""

    @abc.abstractmethod
    def find_cmrts(
        self,
        family: str,
        params: Mapping[str, float],
        *,
        tolerance: float | Mapping[str, float] | None = None,
        character: Mapping[str, Any] | None = None,
        limit: int | None = None,
    ) -> list[CmrtRecord]:
        """Library CMRTs of `family` matching the task parameters `params`.

        Without `tolerance`: every named parameter equal (to 1e-9 relative). With a tolerance
        (one number, or one per name; names not in the mapping must match exactly): every
        named parameter within +-tolerance, ordered nearest first by the Euclidean distance
        over the named parameters, each difference divided by its tolerance (ties: lower
        objective first). Only CMRTs having all named parameters match. `character` keeps
        entries whose character has the given items (e.g. {"height": 1.75}).
        """

    @abc.abstractmethod
    def list_cmrts(
        self, family: str | None = None, *, limit: int | None = None, offset: int = 0
    ) -> tuple[list[CmrtRecord], int]:
        """Library CMRTs (of one family if given), newest first, and the total count."""

    @abc.abstractmethod
    def cmrt_families(self) -> dict[str, int]:
        """Family name -> number of library CMRTs."""

    # ---- PCA bases ----------------------------------------------------------------------
    @abc.abstractmethod
    def add_basis(
        self,
        *,
        family: str,
        k: int,
        mean: Sequence[float],
        components: Sequence[Sequence[float]],
        variance_explained: Sequence[float],
        members: Sequence[str],
        box: Any = None,
    ) -> str:
        """Store a PCA basis and return its id. ValueError if `components` has not `k` rows
        of the length of `mean`."""

    @abc.abstractmethod
    def get_basis(self, basis_id: str) -> BasisRecord:
        """The basis; raises NotFound."""

    @abc.abstractmethod
    def list_bases(self, family: str | None = None) -> list[BasisRecord]:
        """Bases (of one family if given), newest first."""


# =========================================================================================
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


def _job_record(j: Job) -> JobRecord:
    return JobRecord(
        id=j.id, name=j.name, family=j.family, task=j.task, spec=j.spec, seed=j.seed,
        workers=j.workers, status=j.status, stop_rule=j.stop_rule, error=j.error,
        basis_id=j.basis_id, created_at=j.created_at, started_at=j.started_at,
        finished_at=j.finished_at, best_objective=j.best_objective, best_params=j.best_params,
        evaluations=j.evaluations, iterations=j.iterations,
        cancel_requested=bool(j.cancel_requested), driver_owner=j.driver_owner,
        lease_expires_at=j.lease_expires_at, heartbeat_at=j.heartbeat_at,
    )  # fmt: skip


def _generation_record(g: Generation, with_state: bool) -> GenerationRecord:
    return GenerationRecord(
        job_id=g.job_id, iteration=g.iteration, best=g.best, median=g.median, worst=g.worst,
        sigma=g.sigma, best_so_far=g.best_so_far, evaluations=g.evaluations,
        wall_time=g.wall_time, candidates=g.candidates,
        optimizer_state=g.optimizer_state if with_state else None, created_at=g.created_at,
    )  # fmt: skip


def _evaluation_record(e: Evaluation) -> EvaluationRecord:
    return EvaluationRecord(
        job_id=e.job_id, generation=e.generation, index=e.index, params=e.params,
        status=e.status, objective=e.objective, fell=e.fell, attempts=e.attempts,
        cpu_seconds=e.cpu_seconds, error=e.error, details=e.details,
        created_at=e.created_at, updated_at=e.updated_at,
    )  # fmt: skip


def _cmrt_record(c: Cmrt) -> CmrtRecord:
    return CmrtRecord(
        id=c.id, family=c.family, character=c.character, task_parameters=c.task_parameters,
        preparation=c.preparation, duration=c.duration, decay=c.decay, params=c.params,
        knots=c.knots, values=c.values, curve=c.curve, objective=c.objective,
        objective_without=c.objective_without, fell=bool(c.fell),
        fell_without=None if c.fell_without is None else bool(c.fell_without),
        job_id=c.job_id, spec=c.spec, created_at=c.created_at,
    )  # fmt: skip


def _basis_record(b: Basis) -> BasisRecord:
    return BasisRecord(
        id=b.id, family=b.family, k=b.k, mean=b.mean, components=b.components,
        variance_explained=b.variance_explained, members=b.members, box=b.box,
        created_at=b.created_at,
    )  # fmt: skip


def _exact_eps(v: float) -> float:
    return 1e-9 * max(1.0, abs(v))


# ---- the workers' per-candidate statements, built once (see SqlRepository) ---------------
_EV = Evaluation.__table__
_EV_KEY = (
    _EV.c.job_id == bindparam("p_job_id"),
    _EV.c.generation == bindparam("p_generation"),
    _EV.c.index == bindparam("p_index"),
)
_CLAIM_COLUMNS = (
    _EV.c.status,
    _EV.c.attempts,
    _EV.c.params,
    select(Job.__table__.c.status).where(Job.__table__.c.id == _EV.c.job_id).scalar_subquery(),
)
#: Count an attempt at a pending evaluation. One statement: the UPDATE's row lock makes the
#: increment atomic, and a row that is no longer pending is not touched (no row returned).
_CLAIM = (
    update(_EV)
    .where(*_EV_KEY, _EV.c.status == PENDING)
    .values(attempts=_EV.c.attempts + 1, updated_at=bindparam("p_now"))
    .returning(*_CLAIM_COLUMNS)
)
_CLAIM_LOOKUP = select(*_CLAIM_COLUMNS).where(*_EV_KEY)
#: First result wins: only a pending row is updated; a concurrent writer of the same key waits
#: for the row lock, then finds the row no longer pending (rowcount 0).
_STORE_RESULT = (
    update(_EV)
    .where(*_EV_KEY, _EV.c.status == PENDING)
    .values(
        status=bindparam("p_status"),
        objective=bindparam("p_objective"),
        fell=bindparam("p_fell"),
        cpu_seconds=bindparam("p_cpu_seconds"),
        error=bindparam("p_error"),
        details=bindparam("p_details"),
        attempts=case((_EV.c.attempts < 1, 1), else_=_EV.c.attempts),
        updated_at=bindparam("p_now"),
    )
)
_EVALUATION_ID = select(_EV.c.id).where(*_EV_KEY)
#: PostgreSQL: the writes above run in autocommit mode, each statement its own transaction (one
#: round trip), and commit asynchronously by this condition: `set_config(..., true)` sets
#: synchronous_commit for the current transaction only, and the setting in effect when a
#: transaction commits decides how it commits. It is evaluated on the row the statement
#: changes (a statement that changes nothing writes no commit record to flush anyway).
_ASYNC_COMMIT = text("set_config('synchronous_commit', 'off', true) = 'off'")
_CLAIM_PG = _CLAIM.where(_ASYNC_COMMIT)
_STORE_RESULT_PG = _STORE_RESULT.where(_ASYNC_COMMIT)


class SqlRepository(Repository):
    """`Repository` on SQLAlchemy (SQLite or PostgreSQL; engine from `store.db.make_engine`,
    schema from `store.db.init_db`). Thread-safe; use one per process.

    `clock` returns the current aware UTC time (tests inject one to expire leases).

    The workers' per-candidate calls (`claim_evaluation`, `store_result`) are single prebuilt
    Core statements, each its own transaction (no ORM session, no job lock, no counts; on
    PostgreSQL one round trip in autocommit mode): they are the store's share of every
    evaluation's cost. On PostgreSQL they commit with `synchronous_commit = off`: the commit
    returns before its WAL record is flushed to disk, so it is visible to every session at once
    and survives any client dying, but a crash of the server itself (not a clean restart) may
    forget the last ~0.6 s of such commits (3 x wal_writer_delay). That loses no told result:
    WAL is replayed in order, so a crash forgets a suffix of the commit sequence, and every
    transaction that could depend on an evaluation result (the driver's `record_generation`,
    made after it read the results) is committed synchronously later, flushing all earlier WAL
    with it. A forgotten result is pending again and evaluated again (the driver re-sends
    unresolved candidates); a forgotten attempt only lets a candidate start once more.
    Everything else commits synchronously.
    """

    def __init__(self, engine: Engine, *, clock: Clock = utcnow) -> None:
        self.engine = engine
        self._clock = clock
        self._postgres = engine.dialect.name == "postgresql"
        self._claim = _CLAIM_PG if self._postgres else _CLAIM
        self._store_result = _STORE_RESULT_PG if self._postgres else _STORE_RESULT

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

    @staticmethod
    def _lock_job(s: Session, job_id: str) -> Job:
        """Load and lock the job row (PostgreSQL: FOR NO KEY UPDATE; SQLite: the write
        transaction already excludes other writers)."""
        job = s.scalars(
            select(Job).where(Job.id == job_id).with_for_update(key_share=True)
        ).one_or_none()
        if job is None:
            raise NotFound(f"job {job_id} not found")
        return job

    @staticmethod
    def _require_job(s: Session, job_id: str) -> None:
        if s.scalar(select(Job.id).where(Job.id == job_id)) is None:
            raise NotFound(f"job {job_id} not found")

    # ---- jobs ---------------------------------------------------------------------------
    def create_job(self, spec, *, name, family, task, seed=None, workers=1, basis_id=None):
        if workers < 1:
            raise ValueError("workers must be >= 1")
        with self._write() as s:
            if basis_id is not None and s.get(Basis, basis_id) is None:
                raise Conflict(f"basis {basis_id} not found")
            job = Job(
                id=str(uuid.uuid4()), name=name, family=family, task=task,
                spec=_json(dict(spec), "spec"), seed=seed, workers=int(workers), status=QUEUED,
                basis_id=basis_id, created_at=self._clock(), evaluations=0, iterations=0,
                cancel_requested=False,
            )  # fmt: skip
            s.add(job)
            s.flush()
            return _job_record(job)

    def get_job(self, job_id):
        with self._read() as s:
            job = s.get(Job, job_id)
            if job is None:
                raise NotFound(f"job {job_id} not found")
            return _job_record(job)

    def list_jobs(self, *, status=None, family=None, limit=50, offset=0):
        conds = []
        if status is not None:
            statuses = [status] if isinstance(status, str) else list(status)
            conds.append(Job.status.in_(statuses))
        if family is not None:
            conds.append(Job.family == family)
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(Job).where(*conds)) or 0
            rows = s.scalars(
                select(Job)
                .where(*conds)
                .order_by(Job.created_at.desc(), Job.id)
                .limit(limit)
                .offset(offset)
            ).all()
            return [_job_record(j) for j in rows], int(total)

    def set_job_status(self, job_id, status, *, stop_rule=None, error=None):
        if status not in JOB_STATUSES:
            raise ValueError(f"unknown job status {status!r}; statuses are {JOB_STATUSES}")
        sources = [src for src, dests in TRANSITIONS.items() if status in dests]
        now = self._clock()
        values: dict[str, Any] = {"status": status}
        if stop_rule is not None:
            values["stop_rule"] = stop_rule
        if error is not None:
            values["error"] = error
        if status == RUNNING:
            values["started_at"] = now
        if status in TERMINAL_STATUSES:
            values.update(finished_at=now, driver_owner=None, lease_expires_at=None)
        with self._write() as s:
            res = s.execute(
                update(Job)
                .where(Job.id == job_id, Job.status.in_(sources))
                .values(**values)
                .execution_options(synchronize_session=False)
            )
            if res.rowcount == 0:
                current = s.scalar(select(Job.status).where(Job.id == job_id))
                if current is None:
                    raise NotFound(f"job {job_id} not found")
                if current != status:
                    raise InvalidTransition(job_id, current, status)
            return _job_record(s.get(Job, job_id, populate_existing=True))

    def request_cancel(self, job_id):
        now = self._clock()
        with self._write() as s:
            job = self._lock_job(s, job_id)
            if job.status == QUEUED:
                job.status = CANCELLED
                job.cancel_requested = True
                job.finished_at = now
                job.driver_owner = None
                job.lease_expires_at = None
            elif job.status == RUNNING:
                job.cancel_requested = True
            s.flush()
            return _job_record(job)

    def get_optimizer_state(self, job_id):
        with self._read() as s:
            row = s.execute(select(Job.id, Job.optimizer_state).where(Job.id == job_id)).first()
            if row is None:
                raise NotFound(f"job {job_id} not found")
            return row.optimizer_state

    # ---- generations --------------------------------------------------------------------
    def record_generation(
        self, job_id, iteration, *, best, median, worst, sigma, best_so_far, evaluations,
        wall_time, candidates, optimizer_state, best_params=None,
    ):  # fmt: skip
        fig = {
            "best": _num(best, "best"), "median": _num(median, "median"),
            "worst": _num(worst, "worst"), "sigma": _num(sigma, "sigma"),
            "best_so_far": _num(best_so_far, "best_so_far"),
            "wall_time": _num(wall_time, "wall_time"),
        }  # fmt: skip
        cands = _json(candidates, "candidates")
        bparams = _json(best_params, "best_params")
        state = None if optimizer_state is None else bytes(optimizer_state)
        with self._write() as s:
            job = self._lock_job(s, job_id)
            existing = s.scalars(
                select(Generation)
                .options(undefer(Generation.optimizer_state))
                .where(Generation.job_id == job_id, Generation.iteration == iteration)
            ).one_or_none()
            if existing is not None:
                return _generation_record(existing, True)
            gen = Generation(
                job_id=job_id, iteration=int(iteration), evaluations=int(evaluations),
                candidates=cands, optimizer_state=state, created_at=self._clock(), **fig,
            )  # fmt: skip
            s.add(gen)
            if iteration + 1 > job.iterations:
                job.iterations = int(iteration) + 1
                job.evaluations = int(evaluations)
                job.optimizer_state = state
            if job.best_objective is None or fig["best"] < job.best_objective:
                job.best_objective = fig["best"]
                if bparams is not None:
                    job.best_params = bparams
            s.flush()
            return _generation_record(gen, True)

    def latest_generation(self, job_id):
        with self._read() as s:
            self._require_job(s, job_id)
            gen = s.scalars(
                select(Generation)
                .options(undefer(Generation.optimizer_state))
                .where(Generation.job_id == job_id)
                .order_by(Generation.iteration.desc())
                .limit(1)
            ).one_or_none()
            return None if gen is None else _generation_record(gen, True)

    def generations(self, job_id, *, after=-1, with_state=False):
        with self._read() as s:
            self._require_job(s, job_id)
            q = select(Generation).where(
                Generation.job_id == job_id, Generation.iteration > after
            )
            if with_state:
                q = q.options(undefer(Generation.optimizer_state))
            rows = s.scalars(q.order_by(Generation.iteration)).all()
            return [_generation_record(g, with_state) for g in rows]

    # ---- evaluations --------------------------------------------------------------------
    def put_pending_evaluations(self, job_id, generation, params_list):
        rows = [_json(p, "params") for p in params_list]
        now = self._clock()
        with self._write() as s:
            self._lock_job(s, job_id)
            have = set(
                s.scalars(
                    select(Evaluation.index).where(
                        Evaluation.job_id == job_id, Evaluation.generation == generation
                    )
                )
            )
            created = 0
            for i, p in enumerate(rows):
                if i in have:
                    continue
                s.add(
                    Evaluation(
                        job_id=job_id, generation=int(generation), index=i, params=p,
                        status=PENDING, attempts=0, created_at=now, updated_at=now,
                    )  # fmt: skip
                )
                created += 1
            return created

    @staticmethod
    def _lock_evaluation(s: Session, job_id: str, generation: int, index: int) -> Evaluation | None:
        return s.scalars(
            select(Evaluation)
            .where(
                Evaluation.job_id == job_id,
                Evaluation.generation == generation,
                Evaluation.index == index,
            )
            .with_for_update()
        ).one_or_none()

    def start_attempt(self, job_id, generation, index):
        with self._write() as s:
            ev = self._lock_evaluation(s, job_id, generation, index)
            if ev is None:
                raise NotFound(f"evaluation ({job_id}, {generation}, {index}) not found")
            if ev.status == PENDING:
                ev.attempts += 1
                ev.updated_at = self._clock()
                s.flush()
            return _evaluation_record(ev)

    def record_evaluation(
        self, job_id, generation, index, *, objective, fell, cpu_seconds, error=None,
        details=None, params=None,
    ):  # fmt: skip
        obj = _opt_num(objective, "objective")
        cpu = _opt_num(cpu_seconds, "cpu_seconds")
        det = _json(details, "details")
        par = _json(params, "params")
        status = DONE if error is None else EVAL_FAILED
        if status == DONE and obj is None:
            raise ValueError("objective is required unless an error is given")
        now = self._clock()
        with self._write() as s:
            self._lock_job(s, job_id)  # serialises this job's result writes
            ev = self._lock_evaluation(s, job_id, generation, index)
            changed = False
            if ev is None:
                ev = Evaluation(
                    job_id=job_id, generation=int(generation), index=int(index), params=par,
                    status=PENDING, attempts=1, created_at=now, updated_at=now,
                )  # fmt: skip
                s.add(ev)
            if ev.status == PENDING:
                ev.status = status
                ev.objective = obj
                ev.fell = None if fell is None else bool(fell)
                ev.cpu_seconds = cpu
                ev.error = error
                ev.details = det
                ev.attempts = max(ev.attempts, 1)
                if ev.params is None and par is not None:
                    ev.params = par
                ev.updated_at = now
                changed = True
            s.flush()
            counts = self._counts(s, job_id, generation)
            return EvaluationOutcome(_evaluation_record(ev), changed, counts)

    def claim_evaluation(self, job_id, generation, index):
        key = {"p_job_id": job_id, "p_generation": int(generation), "p_index": int(index)}
        with self._evaluation_write() as conn:
            row = conn.execute(self._claim, {**key, "p_now": self._clock()}).first()
            if row is None:  # done, failed or missing: count nothing
                row = conn.execute(_CLAIM_LOOKUP, key).first()
                if row is None:
                    raise NotFound(f"evaluation ({job_id}, {generation}, {index}) not found")
        return EvaluationClaim(
            job_id=job_id, generation=int(generation), index=int(index), status=row[0],
            attempts=int(row[1]), params=row[2], job_status=row[3],
        )  # fmt: skip

    def store_result(
        self, job_id, generation, index, *, objective, fell, cpu_seconds, error=None,
        details=None,
    ):  # fmt: skip
        obj = _opt_num(objective, "objective")
        status = DONE if error is None else EVAL_FAILED
        if status == DONE and obj is None:
            raise ValueError("objective is required unless an error is given")
        key = {"p_job_id": job_id, "p_generation": int(generation), "p_index": int(index)}
        values = {
            "p_status": status, "p_objective": obj, "p_fell": None if fell is None else bool(fell),
            "p_cpu_seconds": _opt_num(cpu_seconds, "cpu_seconds"), "p_error": error,
            "p_details": _json(details, "details"), "p_now": self._clock(),
        }  # fmt: skip
        with self._evaluation_write() as conn:
            if conn.execute(self._store_result, {**key, **values}).rowcount == 1:
                return True
            if conn.execute(_EVALUATION_ID, key).first() is None:
                raise NotFound(f"evaluation ({job_id}, {generation}, {index}) not found")
            return False

    def get_evaluation(self, job_id, generation, index):
        with self._read() as s:
            ev = s.scalars(
                select(Evaluation).where(
                    Evaluation.job_id == job_id,
                    Evaluation.generation == generation,
                    Evaluation.index == index,
                )
            ).one_or_none()
            if ev is None:
                raise NotFound(f"evaluation ({job_id}, {generation}, {index}) not found")
            return _evaluation_record(ev)

    def evaluations(self, job_id, generation):
        with self._read() as s:
            self._require_job(s, job_id)
            rows = s.scalars(
                select(Evaluation)
                .where(Evaluation.job_id == job_id, Evaluation.generation == generation)
                .order_by(Evaluation.index)
            ).all()
            return [_evaluation_record(e) for e in rows]

    @staticmethod
    def _counts(s: Session, job_id: str, generation: int) -> GenerationCounts:
        rows = s.execute(
            select(Evaluation.status, func.count())
            .where(Evaluation.job_id == job_id, Evaluation.generation == generation)
            .group_by(Evaluation.status)
        ).all()
        by = {st: int(n) for st, n in rows}
        return GenerationCounts(
            pending=by.get(PENDING, 0), done=by.get(DONE, 0), failed=by.get(EVAL_FAILED, 0)
        )

    def evaluation_counts(self, job_id, generation):
        with self._read() as s:
            return self._counts(s, job_id, generation)

    # ---- driver lease -------------------------------------------------------------------
    def acquire_driver_lease(self, job_id, owner, ttl_s):
        now = self._clock()
        with self._write() as s:
            res = s.execute(
                update(Job)
                .where(
                    Job.id == job_id,
                    Job.status.in_([QUEUED, RUNNING]),
                    or_(
                        Job.driver_owner.is_(None),
                        Job.driver_owner == owner,
                        Job.lease_expires_at.is_(None),
                        Job.lease_expires_at < now,
                    ),
                )
                .values(
                    driver_owner=owner,
                    lease_expires_at=now + timedelta(seconds=ttl_s),
                    heartbeat_at=now,
                )
                .execution_options(synchronize_session=False)
            )
            if res.rowcount == 0:
                self._require_job(s, job_id)
                return False
            return True

    def renew_driver_lease(self, job_id, owner, ttl_s):
        now = self._clock()
        with self._write() as s:
            res = s.execute(
                update(Job)
                .where(Job.id == job_id, Job.driver_owner == owner)
                .values(lease_expires_at=now + timedelta(seconds=ttl_s), heartbeat_at=now)
                .execution_options(synchronize_session=False)
            )
            return res.rowcount == 1

    def release_driver_lease(self, job_id, owner):
        with self._write() as s:
            s.execute(
                update(Job)
                .where(Job.id == job_id, Job.driver_owner == owner)
                .values(driver_owner=None, lease_expires_at=None)
                .execution_options(synchronize_session=False)
            )

    def orphaned_jobs(self, limit=100):
        now = self._clock()
        with self._read() as s:
            rows = s.scalars(
                select(Job)
                .where(
                    Job.status.in_([QUEUED, RUNNING]),
                    or_(
                        Job.driver_owner.is_(None),
                        Job.lease_expires_at.is_(None),
                        Job.lease_expires_at < now,
                    ),
                )
                .order_by(Job.created_at, Job.id)
                .limit(limit)
            ).all()
            return [_job_record(j) for j in rows]

    # ---- CMRT library -------------------------------------------------------------------
    def add_cmrt(
        self, *, family, character, task_parameters, preparation, duration, decay, params,
        knots, values, curve, objective, objective_without=None, fell=False,
        fell_without=None, job_id=None, spec=None,
    ):  # fmt: skip
        tp = {}
        for k, v in task_parameters.items():
            if not isinstance(k, str) or not 0 < len(k) <= 64:
                raise ValueError(f"task parameter name {k!r}: 1..64 characters")
            tp[k] = _num(v, f"task parameter {k!r}", allow_inf=False)
        row = Cmrt(
            id=str(uuid.uuid4()), family=family, character=_json(dict(character), "character"),
            task_parameters=tp, preparation=_num(preparation, "preparation", allow_inf=False),
            duration=_num(duration, "duration", allow_inf=False),
            decay=_num(decay, "decay", allow_inf=False), params=_json(params, "params"),
            knots=_json(knots, "knots"), values=_json(values, "values"),
            curve=_json(curve, "curve"), objective=_num(objective, "objective"),
            objective_without=_opt_num(objective_without, "objective_without"),
            fell=bool(fell), fell_without=None if fell_without is None else bool(fell_without),
            job_id=job_id, spec=_json(None if spec is None else dict(spec), "spec"),
            created_at=self._clock(),
        )  # fmt: skip
        with self._write() as s:
            if job_id is not None and s.get(Job, job_id) is None:
                raise Conflict(f"job {job_id} not found")
            s.add(row)
            s.flush()
            s.add_all(CmrtParameter(cmrt_id=row.id, name=k, value=v) for k, v in tp.items())
            return row.id

    def get_cmrt(self, cmrt_id):
        with self._read() as s:
            row = s.get(Cmrt, cmrt_id)
            if row is None:
                raise NotFound(f"CMRT {cmrt_id} not found")
            return _cmrt_record(row)

    def find_cmrts(self, family, params, *, tolerance=None, character=None, limit=None):
        target = {k: _num(v, f"parameter {k!r}", allow_inf=False) for k, v in params.items()}
        tol: dict[str, float | None] = {}
        for name in target:
            t = tolerance.get(name) if isinstance(tolerance, Mapping) else tolerance
            if t is not None and (not math.isfinite(t) or t < 0):
                raise ValueError(f"tolerance for {name!r} must be finite and >= 0")
            tol[name] = t
        q = select(Cmrt).where(Cmrt.family == family)
        for name, v in target.items():
            half = tol[name] if tol[name] is not None else _exact_eps(v)
            q = q.where(
                Cmrt.id.in_(
                    select(CmrtParameter.cmrt_id).where(
                        CmrtParameter.name == name,
                        CmrtParameter.value.between(v - half, v + half),
                    )
                )
            )
        with self._read() as s:
            rows = s.scalars(q).all()
            recs = [_cmrt_record(r) for r in rows]
            stored: dict[str, dict[str, float]] = {r.id: {} for r in recs}
            if recs and target:
                for cid, name, value in s.execute(
                    select(CmrtParameter.cmrt_id, CmrtParameter.name, CmrtParameter.value).where(
                        CmrtParameter.cmrt_id.in_(list(stored)),
                        CmrtParameter.name.in_(list(target)),
                    )
                ):
                    stored[cid][name] = value
        if character:
            recs = [r for r in recs if _character_matches(r.character, character)]

        def distance(r: CmrtRecord) -> float:
            total = 0.0
            for name, v in target.items():
                d = stored[r.id][name] - v
                t = tol[name]
                total += (d / t) ** 2 if t else (0.0 if abs(d) <= _exact_eps(v) else math.inf)
            return math.sqrt(total)

        recs.sort(key=lambda r: (distance(r), r.objective, r.created_at, r.id))
        return recs if limit is None else recs[:limit]

    def list_cmrts(self, family=None, *, limit=None, offset=0):
        conds = [] if family is None else [Cmrt.family == family]
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(Cmrt).where(*conds)) or 0
            q = select(Cmrt).where(*conds).order_by(Cmrt.created_at.desc(), Cmrt.id)
            rows = s.scalars(q.limit(limit).offset(offset)).all()
            return [_cmrt_record(r) for r in rows], int(total)

    def cmrt_families(self):
        with self._read() as s:
            rows = s.execute(
                select(Cmrt.family, func.count()).group_by(Cmrt.family).order_by(Cmrt.family)
            ).all()
            return {f: int(n) for f, n in rows}

    # ---- PCA bases ----------------------------------------------------------------------
    def add_basis(self, *, family, k, mean, components, variance_explained, members, box=None):
        m = _json(mean, "mean")
        comps = _json(components, "components")
        if k < 1 or len(comps) != k or any(len(row) != len(m) for row in comps):
            raise ValueError(f"components must be {k} rows of length {len(m)}")
        row = Basis(
            id=str(uuid.uuid4()), family=family, k=int(k), mean=m, components=comps,
            variance_explained=_json(variance_explained, "variance_explained"),
            members=[str(x) for x in members], box=_json(box, "box"), created_at=self._clock(),
        )  # fmt: skip
        with self._write() as s:
            s.add(row)
            return row.id

    def get_basis(self, basis_id):
        with self._read() as s:
            row = s.get(Basis, basis_id)
            if row is None:
                raise NotFound(f"basis {basis_id} not found")
            return _basis_record(row)

    def list_bases(self, family=None):
        conds = [] if family is None else [Basis.family == family]
        with self._read() as s:
            rows = s.scalars(
                select(Basis).where(*conds).order_by(Basis.created_at.desc(), Basis.id)
            ).all()
            return [_basis_record(b) for b in rows]


def _character_matches(stored: Mapping[str, Any], wanted: Mapping[str, Any]) -> bool:
    for key, want in wanted.items():
        have = stored.get(key)
        if isinstance(want, (int, float)) and isinstance(have, (int, float)):
            if abs(float(have) - float(want)) > _exact_eps(float(want)):
                return False
        elif have != want:
            return False
    return True


__all__ = ["Clock", "Repository", "SqlRepository", "utcnow"]
