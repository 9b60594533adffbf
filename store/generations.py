"""Generations and evaluations of a job: `EvaluationRepository` (the contract) and
`SqlEvaluations` (SQLAlchemy; the workers' per-candidate writes are prebuilt statements)."""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import Any

from sqlalchemy import bindparam, case, func, insert, select, text, update
from sqlalchemy.orm import Session, undefer

from store.errors import NotFound
from store.models import EvaluationRow as Evaluation
from store.models import GenerationRow as Generation
from store.models import JobRow as Job
from store.records import (
    DONE,
    EVAL_FAILED,
    PENDING,
    EvaluationClaim,
    EvaluationRecord,
    GenerationCounts,
    GenerationRecord,
)
from store.sql import (
    SqlBase,
    _generation_record,
    _json,
    _num,
    _opt_num,
)

# ---- the workers' per-candidate statements, built once (see SqlEvaluations) ---------------
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
        fingerprint=bindparam("p_fingerprint"),
        attempts=case((_EV.c.attempts < 1, 1), else_=_EV.c.attempts),
        updated_at=bindparam("p_now"),
    )
)
_EVALUATION_ID = select(_EV.c.id).where(*_EV_KEY)
_GEN = Generation.__table__
_JOB = Job.__table__
_JOB_ID = select(_JOB.c.id)
#: An `EvaluationRecord`'s columns, read as Core rows (no ORM objects: the driver's hot reads).
_EVALUATION_COLUMNS = tuple(_EV.c[f.name] for f in fields(EvaluationRecord))
_GENERATION_COLUMNS = tuple(_GEN.c[f.name] for f in fields(GenerationRecord))
_EVALUATION_COLUMNS_NO_PARAMS = tuple(c for c in _EVALUATION_COLUMNS if c.name != "params")
#: Give back an attempt of a pending evaluation (a graceful stop cut it short).
_RELEASE_ATTEMPT = (
    update(_EV)
    .where(*_EV_KEY, _EV.c.status == PENDING, _EV.c.attempts > 0)
    .values(attempts=_EV.c.attempts - 1, updated_at=bindparam("p_now"))
)
#: PostgreSQL: the writes above run in autocommit mode, each statement its own transaction (one
#: round trip), and commit asynchronously by this condition: `set_config(..., true)` sets
#: synchronous_commit for the current transaction only, and the setting in effect when a
#: transaction commits decides how it commits. It is evaluated on the row the statement
#: changes (a statement that changes nothing writes no commit record to flush anyway).
_ASYNC_COMMIT = text("set_config('synchronous_commit', 'off', true) = 'off'")
_CLAIM_PG = _CLAIM.where(_ASYNC_COMMIT)
_STORE_RESULT_PG = _STORE_RESULT.where(_ASYNC_COMMIT)

class EvaluationRepository(abc.ABC):
    """Generation records (with the pickled optimizer) and per-candidate evaluations."""

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
    def claim_evaluation(self, job_id: str, generation: int, index: int) -> EvaluationClaim:
        """A worker's start on one candidate, in one atomic step: count one more attempt if
        the evaluation is pending and return its status, attempts and params together with
        the job's status (`EvaluationClaim`).

        An evaluation no longer pending (done or failed) is returned as it is with nothing
        counted (the caller skips the work); the caller compares `attempts` with its limit and
        calls `fail_evaluation` when it is exceeded, and skips the work when `job_terminal`.
        The attempt is visible to every other process as soon as this returns (a worker
        killed right after loses nothing).
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
        fingerprint: str | None = None,
    ) -> bool:
        """Store a worker's result of an existing evaluation (the driver polls
        `evaluation_counts` to see the generation resolved), with the numeric fingerprint of
        the process that computed it (`sim.fingerprint`) when given.

        Status `done`, or `failed` when `error` is given. First result wins, atomically: only
        a pending evaluation is changed, and True is returned only by the write that moved
        it out of `pending`; a repeated or late write changes nothing and returns False.
        `params` are kept, `attempts` too (raised to 1 if no attempt was counted); a missing
        row is not created.
        The result is visible to every other process as soon as this returns. Durability on
        PostgreSQL: committed asynchronously (see `SqlRepository`): a crash of the database
        server itself may turn the last fraction of a second of results back to pending
        (they are evaluated again), never one that a later commit depended on.
        Raises NotFound when the evaluation does not exist; ValueError for a NaN objective or
        a missing objective without `error`.
        """

    @abc.abstractmethod
    def release_attempt(self, job_id: str, generation: int, index: int) -> bool:
        """Give back one attempt of a pending evaluation (`attempts - 1`, never below 0): for
        an attempt cut short by a graceful stop (the process shutting down stopped it), which
        must not count toward the caller's limit. True if an attempt was given back; a done or
        failed evaluation is left unchanged (False). Raises NotFound for an unknown
        evaluation."""

    def fail_evaluation(self, job_id: str, generation: int, index: int, error: str) -> bool:
        """Mark a pending evaluation failed (e.g. attempts exhausted): `store_result` with
        `error`; True if this call moved it out of `pending`."""
        return self.store_result(
            job_id, generation, index, objective=None, fell=None, cpu_seconds=None, error=error
        )

    @abc.abstractmethod
    def evaluations(
        self, job_id: str, generation: int, *, params: bool = True
    ) -> list[EvaluationRecord]:
        """The generation's evaluations in index order (empty if none); their `params` None
        unless `params` (a driver has them already). Raises NotFound for an unknown job."""

    @abc.abstractmethod
    def pending_indices(self, job_id: str, generation: int) -> list[int]:
        """The indices of the generation's evaluations still pending, ascending (no row
        decoded: what a driver sends)."""

    @abc.abstractmethod
    def evaluation_counts(self, job_id: str, generation: int) -> GenerationCounts:
        """Pending / done / failed counts of a generation."""

    @abc.abstractmethod
    def evaluation_fingerprints(self, job_id: str) -> list[str]:
        """The distinct numeric fingerprints of the processes that evaluated the job's
        candidates (`store_result`'s `fingerprint`), sorted; empty when none was recorded.
        Raises NotFound."""

    @abc.abstractmethod
    def evaluation_summary(self, job_id: str, *, after: int = -1) -> list[dict[str, int]]:
        """Per generation with evaluations (generation > `after`, plus the final re-evaluation,
        generation -1, whenever it exists), in one query: `{"generation", "population",
        "done", "pending", "failed", "attempts", "repeated"}` (`repeated`: attempts beyond the
        first, summed), final generation first, then ascending. Raises NotFound."""


class SqlEvaluations(SqlBase, EvaluationRepository):
    @property
    def _claim(self) -> Any:
        return _CLAIM_PG if self._postgres else _CLAIM

    @property
    def _store_result(self) -> Any:
        return _STORE_RESULT_PG if self._postgres else _STORE_RESULT

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
        # Core statements in one transaction, no ORM objects (the driver writes one per
        # generation); the job's row is locked and only the two columns read that decide
        with self.engine.begin() as conn:
            job = self._lock_job_columns(conn, job_id, _JOB.c.iterations, _JOB.c.best_objective)
            existing = conn.execute(
                select(*_GENERATION_COLUMNS)
                .where(_GEN.c.job_id == job_id, _GEN.c.iteration == iteration)
            ).first()
            if existing is not None:
                return GenerationRecord(**existing._mapping)
            row = {
                "job_id": job_id, "iteration": int(iteration), "evaluations": int(evaluations),
                "candidates": cands, "optimizer_state": state, "created_at": self._clock(),
                **fig,
            }  # fmt: skip
            conn.execute(insert(_GEN), [row])
            changes: dict[str, Any] = {}
            if iteration + 1 > job.iterations:
                changes.update(iterations=int(iteration) + 1, evaluations=int(evaluations),
                               optimizer_state=state)
            if job.best_objective is None or fig["best"] < job.best_objective:
                changes["best_objective"] = fig["best"]
                if bparams is not None:
                    changes["best_params"] = bparams
            if changes:
                conn.execute(update(_JOB).where(_JOB.c.id == job_id).values(**changes))
            return GenerationRecord(**row)

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
        with self.engine.begin() as conn:  # Core, as record_generation
            self._lock_job_columns(conn, job_id, _JOB.c.id)
            have = set(
                conn.scalars(
                    select(_EV.c.index).where(
                        _EV.c.job_id == job_id, _EV.c.generation == generation
                    )
                )
            )
            new = [
                {"job_id": job_id, "generation": int(generation), "index": i, "params": p,
                 "status": PENDING, "attempts": 0, "created_at": now, "updated_at": now}
                for i, p in enumerate(rows) if i not in have
            ]
            if new:  # one bulk INSERT of the table, no ORM objects: the unit of work it
                # replaces took 17 % of the job driver's CPU (bench/capacity.py, profiled)
                conn.execute(insert(_EV), new)
            return len(new)

    def claim_evaluation(self, job_id, generation, index):
        key = {"p_job_id": job_id, "p_generation": int(generation), "p_index": int(index)}
        with self._evaluation_write() as conn:
            row = conn.execute(self._claim, {**key, "p_now": self._clock()}).first()
            if row is None:  # done, failed or missing: count nothing
                row = conn.execute(_CLAIM_LOOKUP, key).first()
                if row is None:
                    raise NotFound(f"evaluation ({job_id!a}, {generation}, {index}) not found")
        return EvaluationClaim(
            job_id=job_id, generation=int(generation), index=int(index), status=row[0],
            attempts=int(row[1]), params=row[2], job_status=row[3],
        )  # fmt: skip

    def store_result(
        self, job_id, generation, index, *, objective, fell, cpu_seconds, error=None,
        details=None, fingerprint=None,
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
            "p_fingerprint": None if fingerprint is None else str(fingerprint)[:64],
        }  # fmt: skip
        with self._evaluation_write() as conn:
            if conn.execute(self._store_result, {**key, **values}).rowcount == 1:
                return True
            if conn.execute(_EVALUATION_ID, key).first() is None:
                raise NotFound(f"evaluation ({job_id!a}, {generation}, {index}) not found")
            return False

    def release_attempt(self, job_id, generation, index):
        key = {"p_job_id": job_id, "p_generation": int(generation), "p_index": int(index)}
        with self._evaluation_write() as conn:
            if conn.execute(_RELEASE_ATTEMPT, {**key, "p_now": self._clock()}).rowcount == 1:
                return True
            if conn.execute(_EVALUATION_ID, key).first() is None:
                raise NotFound(f"evaluation ({job_id!a}, {generation}, {index}) not found")
            return False

    def evaluations(self, job_id, generation, *, params=True):
        columns = _EVALUATION_COLUMNS if params else _EVALUATION_COLUMNS_NO_PARAMS
        with self._read_statement() as conn:
            rows = conn.execute(
                select(*columns)
                .where(_EV.c.job_id == job_id, _EV.c.generation == generation)
                .order_by(_EV.c.index)
            ).all()
            if not rows and conn.execute(_JOB_ID.where(_JOB.c.id == job_id)).first() is None:
                raise NotFound(f"job {job_id!a} not found")
        return [EvaluationRecord(**r._mapping, **({} if params else {"params": None}))
                for r in rows]

    def pending_indices(self, job_id, generation):
        with self._read_statement() as conn:
            return list(conn.scalars(
                select(_EV.c.index)
                .where(_EV.c.job_id == job_id, _EV.c.generation == generation,
                       _EV.c.status == PENDING)
                .order_by(_EV.c.index)
            ))

    @staticmethod
    def _counts(s: Session | Any, job_id: str, generation: int) -> GenerationCounts:
        rows = s.execute(
            select(_EV.c.status, func.count())
            .where(_EV.c.job_id == job_id, _EV.c.generation == generation)
            .group_by(_EV.c.status)
        ).all()
        by = {st: int(n) for st, n in rows}
        return GenerationCounts(
            pending=by.get(PENDING, 0), done=by.get(DONE, 0), failed=by.get(EVAL_FAILED, 0)
        )

    def evaluation_counts(self, job_id, generation):
        with self._read_statement() as conn:
            return self._counts(conn, job_id, generation)

    def evaluation_fingerprints(self, job_id):
        ev = Evaluation
        with self._read() as s:
            self._require_job(s, job_id)
            rows = s.execute(
                select(ev.fingerprint).distinct()
                .where(ev.job_id == job_id, ev.fingerprint.is_not(None))
            ).all()
        return sorted(r[0] for r in rows)

    def evaluation_summary(self, job_id, *, after=-1):
        ev = Evaluation
        with self._read() as s:
            self._require_job(s, job_id)
            rows = s.execute(
                select(
                    ev.generation,
                    func.count(),
                    func.sum(case((ev.status == DONE, 1), else_=0)),
                    func.sum(case((ev.status == PENDING, 1), else_=0)),
                    func.sum(case((ev.status == EVAL_FAILED, 1), else_=0)),
                    func.sum(ev.attempts),
                    func.sum(case((ev.attempts > 1, ev.attempts - 1), else_=0)),
                )
                .where(ev.job_id == job_id, (ev.generation > after) | (ev.generation == -1))
                .group_by(ev.generation)
                .order_by(ev.generation)
            ).all()
        keys = ("generation", "population", "done", "pending", "failed", "attempts", "repeated")
        return [{k: int(v or 0) for k, v in zip(keys, r, strict=True)} for r in rows]

