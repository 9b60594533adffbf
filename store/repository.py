"""The repository: the only way the rest of the service reads and writes persistent state.

`Repository` states the contract (docstrings); `SqlRepository(engine)` implements it with
SQLAlchemy on SQLite (embedded default) and PostgreSQL (deployed). Every method is one
transaction; methods return frozen records from `store.records`, never ORM objects, and raise
the errors of `store.errors`. Several processes (the driver, local pool workers, Celery workers,
the HTTP service) may use the same database at once: every write that others race on is atomic.

The contract is split by aggregate, each part with its docstrings: `store.jobs.JobRepository`
(jobs, driver lease), `store.generations.EvaluationRepository` (generations, evaluations),
`store.library.LibraryRepository` (CMRT library, PCA bases), `store.families.FamilyRepository`
(families of CMRTs, whose runs are jobs), `store.characters.CharacterRepository` (named
character definitions); `Repository` is all five and `SqlRepository` their SQLAlchemy
implementations together.

Typical job flow (docs/service.md, "Architecture"):

1. service: `create_job(...)` -> queued.
2. driver: `acquire_driver_lease(job, me, ttl)`; `set_job_status(job, "running")`; keeps the
   lease with `renew_driver_lease` and gives it up when the lease is lost.
3. driver, each generation g: ask candidates (from `latest_generation(job).optimizer_state`, or
   a fresh optimizer for g = 0); `put_pending_evaluations(job, g, candidates)`; dispatch.
4. worker, per candidate: `c = claim_evaluation(job, g, i)`; if `c.status != "pending"` or
   `c.job_terminal` skip; if `c.attempts > max_attempts` -> `fail_evaluation(...)`; else
   evaluate `c.params` and `store_result(...)` (first result wins). The driver polls
   `evaluation_counts(job, g)` until every evaluation is resolved.
5. closing a generation: tell the optimizer the objectives of `evaluations(job, g)` and
   `record_generation(job, g, ...)` before asking g + 1 (idempotent: if another process closed
   it first, continue from the stored record's optimizer_state).
6. driver: `set_job_status(job, "converged" | "stopped" | "failed" | "cancelled", ...)`,
   checking `cancel_requested(job)` (the flag alone) between generations; `job_cmrt(job)` finds its
   library entry, `add_cmrt(entry)` adds one.
"""

from __future__ import annotations

from store.characters import CharacterRepository, SqlCharacters
from store.families import FamilyRepository, SqlFamilies
from store.generations import EvaluationRepository, SqlEvaluations
from store.jobs import JobRepository, SqlJobs
from store.library import LibraryRepository, SqlLibrary
from store.sql import Clock, utcnow


class Repository(JobRepository, EvaluationRepository, LibraryRepository, FamilyRepository,
                 CharacterRepository):
    """Persistent state of jobs, generations, evaluations, the CMRT library, PCA bases,
    families and named character definitions."""


class SqlRepository(SqlJobs, SqlEvaluations, SqlLibrary, SqlFamilies, SqlCharacters,
                    Repository):
    """`Repository` on SQLAlchemy (SQLite or PostgreSQL; engine from `store.db.make_engine`,
    schema from `store.db.init_db`). Thread-safe; use one per process.

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



__all__ = ["Clock", "Repository", "SqlRepository", "utcnow"]
