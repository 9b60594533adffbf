"""Candidate evaluations against the store: `run_candidates`, the one function that claims,
evaluates and records candidates, on both paths: the body of the Celery tasks (each candidate
evaluated in this process, claimed just before it runs) and the embedded service's local pool
(`worker.executors.LocalPoolExecutor`: every candidate claimed, then evaluated in the pool).

Idempotent and attempt-counted, with two store calls per candidate:
  1. `claim_evaluation` atomically counts an attempt at the pending (job, generation, index)
     row and returns its params with the job's status; a row already done or failed is skipped
     (a duplicate or re-delivered message costs nothing), and so is a candidate of a job that
     has finished meanwhile (cancelled or failed);
  2. past `max_attempts` the evaluation is failed with a clear error instead of run again (a
     candidate that kills its worker every time fails its job instead of looping);
  3. the objective runs (`JobSpecs`: the job's spec hash, read from the store once per process
     and job, keys the process's one spec cache `optim.objective.SPECS`, which parses the
     stored spec only on a miss and keeps one simulator per spec);
  4. `store_result` upserts the small result keyed by (job, generation, index): the first
     result wins, a repeated one changes nothing. It carries this process's numeric fingerprint
     (worker.fingerprints; on the local pool's path, the process that started the pool's).
An exception inside the objective is a property of the candidate (deterministic): it is stored as
`done` with the worst objective (optim's FAILED_OBJECTIVE) and the error in `details`, so CMA-ES
ranks it last, exactly as the CLI's executors do.

A lost database connection (PostgreSQL restarted, the session killed, the server briefly
unreachable) does not fail the candidate: each store call is tried again on a fresh connection
for up to `RECONNECT_SECONDS` (`with_reconnect`), so a finished evaluation is stored once the
database answers again. That is what lets the Celery workers skip SQLAlchemy's ping before every
use of a pooled connection (worker.tasks).
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from sqlalchemy.exc import DBAPIError, OperationalError

from application.jobs import job_spec
from cmrt.lru import LRU
from optim.errors import EvaluationError
from optim.executors import EvalOutcome, evaluate_one
from optim.objective import SPECS
from sim.spec import TaskSpec
from store import NotFound, Repository
from store.records import DONE, PENDING
from worker import faults
from worker.fingerprints import process_fingerprint

log = logging.getLogger(__name__)

T = TypeVar("T")
#: How `run_candidates` gets claimed candidates evaluated elsewhere (a process pool):
#: `pool_run(objective, params, on_result)` calls `on_result(position, outcome | EvaluationError)`
#: once per candidate (an EvaluationError: its process died, the attempt counts).
PoolRun = Callable[[Any, list[np.ndarray], Callable[[int, Any], None]], None]


class JobFailedError(Exception):
    """The job cannot continue; the message is stored as its error."""


class DriverInterruptError(Exception):
    """The driver must stop now; the subclass says why (caught by type): `DriverShutdownError`,
    `JobCancelledError`, `LeaseLostError` (see `worker.driver.JobDriver.check`)."""


class DriverShutdownError(DriverInterruptError):
    """A graceful stop of the driver's process: the job stays running for the next driver,
    and the attempts it cut short are given back (not counted as crashes)."""

    def __init__(self, msg: str = "shutdown") -> None:
        super().__init__(msg)


class JobCancelledError(DriverInterruptError):
    """The job's cancellation was requested: the driver revokes what it sent and cancels it."""

    def __init__(self, msg: str = "cancel") -> None:
        super().__init__(msg)


class LeaseLostError(DriverInterruptError):
    """Another driver took the job's lease: this one stops without touching the job."""

    def __init__(self, msg: str = "lease lost") -> None:
        super().__init__(msg)


def attempts_exhausted_message(generation: int, index: int, attempts: int) -> str:
    """The error of a candidate given up on. Only attempts whose process ended without a
    result count (a graceful stop gives its attempts back: `Repository.release_attempt`), so
    every counted attempt is one where the evaluating process died or was killed."""
    return (
        f"candidate {index} of generation {generation} was started {attempts} times and its "
        "worker process died every time (crash, out of memory, or killed past the time limit); "
        "giving up on it"
    )


class JobSpecs:
    """Job id -> the hash of its spec (a job's spec never changes), over the process's one
    spec cache (`optim.objective.SPECS`, which holds the typed specs, their simulators and
    objectives): the store is read once per job, the spec parsed once per spec."""

    def __init__(self, size: int = 1024) -> None:
        self._hashes: LRU[str, str] = LRU(size)  # thread-safe: the driver threads share one

    def get(self, repo: Repository, job_id: str) -> tuple[TaskSpec, Any]:
        """The job's (typed spec, objective)."""
        canonical = job_spec(repo, job_id, self._hashes.get(job_id))
        self._hashes.put(job_id, canonical.hash)
        return canonical.spec, SPECS.objective(canonical)


#: EvalOutcome fields stored in an evaluation row's `details` when they are not None.
OUTCOME_DETAILS = ("fall_time", "fall_direction", "task_success")


def outcome_fields(out: EvalOutcome, worker: str | None = None) -> dict[str, Any]:
    """store_result / record_evaluation keyword arguments for an objective outcome (see the
    module docstring)."""
    details: dict[str, Any] = {}
    if out.error is not None:
        details["error"] = out.error
    # the clip's verdict beyond `fell` (issue 10: evaluation records say how and whether the
    # task succeeded); only what applies, so a quiet-stance row stays small
    for key in OUTCOME_DETAILS:
        if getattr(out, key) is not None:
            details[key] = getattr(out, key)
    if out.cut:  # the objective is a lower bound: the certain last of its generation
        details["cut"] = True
    if worker:
        details["worker"] = worker
    return {
        "objective": float(out.objective),
        "fell": bool(out.fell),
        "cpu_seconds": float(out.cpu_seconds),
        "details": details or None,
    }


def open_worker_repository(url: str) -> Repository:
    """The repository of an evaluation worker process (no schema migration: the API does it).

    No ping before each use of a pooled connection (it would be 2 of the 4 database round
    trips per candidate): `run_candidates` retries its store calls on a fresh connection when the
    database connection was lost (`with_reconnect`).
    """
    from store import SqlRepository, make_engine

    return SqlRepository(make_engine(url, pool_pre_ping=False))


#: How long a store call of `run_candidates` is retried while the database connection is lost.
RECONNECT_SECONDS = 30.0


def with_reconnect(call: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """`call(*args, **kwargs)` (a repository's method, named in the log), tried again
    (backing off from 0.05 to 2 s, for up to `RECONNECT_SECONDS`) when it fails on a lost or
    refused database connection or another transient database error (SQLAlchemy's
    OperationalError; SQLAlchemy has already discarded the dead connections, so the next try
    opens a fresh one).

    Safe for the calls of `run_candidates`: a read, a first-result-wins write, or a claim, which
    repeated after a commit whose reply was lost counts one attempt too many (erring toward
    failing a candidate early, never toward looping).
    """
    deadline = time.monotonic() + RECONNECT_SECONDS
    delay = 0.05
    while True:
        try:
            return call(*args, **kwargs)
        except DBAPIError as err:
            if not (err.connection_invalidated or isinstance(err, OperationalError)):
                raise
            if time.monotonic() + delay > deadline:
                raise
            log.warning("database call %s failed (%s: %s); trying again in %.2f s",
                        call.__name__, type(err.orig).__name__,
                        str(err.orig).strip().splitlines()[0] if err.orig else "", delay)
            time.sleep(delay)
            delay = min(2.0 * delay, 2.0)


def run_candidates(
    repo: Repository,
    job_id: str,
    generation: int,
    indices: list[int],
    *,
    max_attempts: int,
    cache: JobSpecs,
    pool_run: PoolRun | None = None,
    worker_name: str | None = None,
    notify: Callable[[str, int, int], Any] | None = None,
) -> list[dict[str, Any]]:
    """Claim, evaluate and store the candidates `indices` of (job, generation); one small JSON
    dict per candidate, in order (see the module docstring).

    Without `pool_run` each candidate is claimed just before it runs in this process (a worker
    killed mid-task has counted an attempt only for the candidate it was running), after the
    fault-injection hooks (worker.faults). With `pool_run` every candidate is claimed, then the
    claimed ones go to the pool together; one whose process died keeps its counted attempt and
    stays pending (the caller claims it again), and a `DriverShutdownError` gives
    back the attempts of the candidates it left unfinished (`Repository.release_attempt`).
    `notify(job_id, generation, index)` is called once a candidate is resolved in the store
    (stored here, or found resolved already): the driver's wake-up (worker.notify). The job's
    typed spec and objective come from `cache` (the store read once per process and job, the
    spec parsed at most once per process)."""
    run = CandidateRun(repo, job_id, generation, max_attempts=max_attempts, cache=cache,
                       worker_name=worker_name or socket.gethostname(), notify=notify)
    if pool_run is None:
        run.evaluate_here(indices)
    else:
        run.evaluate_in_pool(indices, pool_run)
    return [run.results[i] for i in indices]


class CandidateRun:
    """The candidates of one `run_candidates` call: `claim` (an attempt counted, or the reason
    to skip), evaluation here or in a pool, `record` (the result stored, first one wins, and
    the driver notified). `results` holds each candidate's small JSON dict."""

    def __init__(self, repo: Repository, job_id: str, generation: int, *, max_attempts: int,
                 cache: JobSpecs, worker_name: str,
                 notify: Callable[[str, int, int], Any] | None) -> None:
        self.repo, self.job_id, self.generation = repo, job_id, generation
        self.max_attempts, self.cache = max_attempts, cache
        self.worker_name, self.notify = worker_name, notify
        self.results: dict[int, dict[str, Any]] = {}
        self._loaded: tuple[TaskSpec, Any] | None = None

    def objective(self) -> tuple[TaskSpec, Any]:
        """The job's typed spec and objective (read once per call, from the process's cache)."""
        if self._loaded is None:
            self._loaded = with_reconnect(self.cache.get, self.repo, self.job_id)
        return self._loaded

    def claim(self, index: int) -> np.ndarray | None:
        """The candidate's params once claimed, or None (resolved: see `results`)."""
        job_id, generation = self.job_id, self.generation
        try:
            c = with_reconnect(self.repo.claim_evaluation, job_id, generation, index)
        except NotFound:
            self.results[index] = {"status": "missing"}
            return None
        if c.status != PENDING:
            self.results[index] = {"status": c.status, "skipped": True}
        elif c.attempts > self.max_attempts:
            msg = attempts_exhausted_message(generation, index, c.attempts - 1)
            with_reconnect(self.repo.fail_evaluation, job_id, generation, index, msg)
            log.error("job %s: %s", job_id, msg)
            self.results[index] = {"status": "failed", "attempts": c.attempts}
        elif c.job_terminal:  # cancelled or failed meanwhile: don't spend CPU on it
            self.results[index] = {"status": "skipped", "job_status": c.job_status}
            return None
        else:
            self.results[index] = {"status": "claimed", "attempts": c.attempts}
            return np.asarray(c.params, dtype=float)
        if self.notify is not None:
            self.notify(job_id, generation, index)
        return None

    def record(self, index: int, out: EvalOutcome | EvaluationError) -> None:
        """Store the candidate's outcome (a lost process: nothing stored, the attempt counts)."""
        job_id, generation = self.job_id, self.generation
        if isinstance(out, EvaluationError):  # its process died: the attempt counts
            log.warning("job %s generation %d candidate %d: %s", job_id, generation, index, out)
            self.results[index] = {"status": "lost", "error": str(out)}
            return
        changed = with_reconnect(self.repo.store_result, job_id, generation, index,
                                 **outcome_fields(out, self.worker_name),
                                 fingerprint=process_fingerprint())
        if self.notify is not None:
            self.notify(job_id, generation, index)
        self.results[index] = {"status": DONE if changed else "duplicate",
                               "objective": float(out.objective),
                               "attempts": self.results[index]["attempts"], "changed": changed}

    def evaluate_here(self, indices: list[int]) -> None:
        """Each candidate claimed just before it runs in this process."""
        for index in indices:
            params = self.claim(index)
            if params is None:
                continue
            spec_, fn = self.objective()
            faults.maybe_crash(spec_.name, self.generation, index)
            faults.maybe_delay(spec_.name, self.generation, index)
            self.record(index, evaluate_one(fn, params))

    def evaluate_in_pool(self, indices: list[int], pool_run: PoolRun) -> None:
        """Every candidate claimed, then the claimed ones evaluated together by `pool_run`."""
        todo = [(i, p) for i in indices if (p := self.claim(i)) is not None]
        if not todo:
            return
        try:
            pool_run(self.objective()[1], [p for _, p in todo],
                     lambda pos, out: self.record(todo[pos][0], out))
        except DriverShutdownError:  # a graceful stop is not a crash: un-count them
            for i, _ in todo:
                if self.results[i]["status"] == "claimed":
                    self.repo.release_attempt(self.job_id, self.generation, i)
            raise


