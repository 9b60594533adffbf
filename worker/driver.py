"""The job driver: the shared CMA-ES loop (`optim.loop`) of one job, run against the store.

`StoreEvaluator` and `StoreRunState` are the loop's evaluator and persistence for the service;
the loop itself (ask, evaluate, tell, stop rules, the final evaluation) is `optim.loop`'s.
One driver per job at a time, enforced by a lease in the store (renewed by a heartbeat thread;
a driver that loses it stops at once). Each generation:

    restore the optimizer from the latest stored generation (or start one from the spec/seed)
    ask -> store the candidates as pending evaluations (idempotent: a restarted driver asks
           the same candidates again, the optimizer owning its RNG, and finds the results that
           were already stored)
    executor.evaluate (local pool | Celery) until every evaluation is resolved
    tell -> record the generation with the pickled optimizer and its figures in one transaction
    check cancellation and the stopping rules

At the end the best candidate and the flat spline (the no-CMRT baseline) are evaluated once more
(generation -1, same executor path); the better of the two goes into the library (an entry is
never worse than no anticipation; its `winner` says which) and the job ends `converged`
(stopping rule threshold / slow_convergence / CMA-ES' own) or `stopped` (max_evaluations).
A failed evaluation (attempts exhausted) or a generation where every candidate raised fails the
job with the reason; a lost database connection only ends the driver (the job is resumed later).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy.exc import SQLAlchemyError

from application.bases import basis_from_record
from application.jobs import job_spec
from application.library import library_entry
from cmrt.settings import Settings
from optim.cmaes import CmaOptimizer, GenerationStats
from optim.errors import EvaluationError
from optim.loop import (
    FINAL_GENERATION,
    FinalEvaluation,
    SearchSpace,
    final_evaluation,
    new_optimizer,
    run_generations,
)
from optim.outcome import EvalOutcome
from optim.robust import cut_allowed
from optim.run import result_of
from sim.errors import SpecError
from sim.spec import TaskSpec
from store import JobStart, NotFound, Repository, StoreError
from store.records import (
    CANCELLED,
    CONVERGED,
    EVAL_FAILED,
    FAILED,
    PENDING,
    QUEUED,
    RUNNING,
    STOPPED,
)
from worker.candidates import (
    DriverInterruptError,
    DriverShutdownError,
    JobCancelledError,
    LeaseLostError,
)
from worker.executors import GenerationExecutor, JobFailedError

log = logging.getLogger(__name__)

#: Stopping rules that end a job `stopped` rather than `converged`.
STOPPED_RULES = frozenset({"max_evaluations"})
#: How old a job's cancel flag may be when its driver checks it between two results, s.
CANCEL_POLL_S = 0.5


def make_owner() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class _Lease:
    """Heartbeat thread renewing the driver lease; `lost` is set if another owner took it."""

    def __init__(self, repo: Repository, job_id: str, owner: str, ttl: float) -> None:
        self.repo, self.job_id, self.owner, self.ttl = repo, job_id, owner, ttl
        self.lost = threading.Event()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, name=f"lease-{job_id[:8]}", daemon=True)

    def start(self) -> None:
        self._t.start()

    def _run(self) -> None:
        while not self._stop.wait(self.ttl / 3.0):
            try:
                if not self.repo.renew_driver_lease(self.job_id, self.owner, self.ttl):
                    self.lost.set()
                    return
            except Exception as err:  # noqa: BLE001 - database blip: retry next beat
                log.warning("job %s: lease renewal failed: %s", self.job_id, err)

    def stop(self) -> None:
        self._stop.set()
        if self._t.is_alive():
            self._t.join(timeout=5)


class CancelFlags:
    """The cancel flags of the jobs driven in one process, read for all of them in one query
    at most every `interval` s: a driver checks its job's flag while it waits for results, and
    a process driving many jobs reads them once per tick, not once per job."""

    def __init__(self, repo: Repository, interval: float = CANCEL_POLL_S) -> None:
        self.repo, self.interval = repo, interval
        self._lock = threading.Lock()
        self._jobs: dict[str, int] = {}  # job id -> drivers of it here
        self._flags: dict[str, bool] = {}
        self._read_at = -float("inf")

    def watch(self, job_id: str) -> None:
        """Read the job's flag from now on (until `unwatch`)."""
        with self._lock:
            self._jobs[job_id] = self._jobs.get(job_id, 0) + 1

    def unwatch(self, job_id: str) -> None:
        with self._lock:
            left = self._jobs.get(job_id, 0) - 1
            if left > 0:
                self._jobs[job_id] = left
            else:
                self._jobs.pop(job_id, None)
                self._flags.pop(job_id, None)

    def requested(self, job_id: str) -> bool:
        """Whether a cancel of the job was asked for, as read at most `interval` s ago.
        Raises NotFound for a job that does not exist."""
        with self._lock:
            now = time.monotonic()
            if now - self._read_at >= self.interval or job_id not in self._flags:
                self._flags = self.repo.cancel_flags({*self._jobs, job_id})
                self._read_at = now
            flag = self._flags.get(job_id)
        if flag is None:
            raise NotFound(f"job {job_id!a} not found")
        return flag


class StoreEvaluator:
    """`optim.loop.CandidateEvaluator` of a job: the candidates become pending evaluations in
    the store (idempotent), the generation executor resolves them, and the stored rows become
    outcomes. A failed row (attempts exhausted) or a stored candidate that differs from the one
    asked again after a restart fails the job (JobFailedError). `cut_margin`: the generations'
    certain last may stop early (`optim.rankcut`) where the executor can; the final evaluation
    is never cut."""

    def __init__(self, driver: JobDriver, cut_margin: float | None = None) -> None:
        self.driver, self.cut_margin = driver, cut_margin

    def evaluate(self, generation: int, candidates: Any) -> list[EvalOutcome]:
        d = self.driver
        d.check(force=True)
        full = [list(map(float, p)) for p in candidates]
        if d.repo.put_pending_evaluations(d.job_id, generation, full) < len(full):
            self._check_stored(generation, full)  # rows of an earlier driver: the same?
        cut = None if generation == FINAL_GENERATION else self.cut_margin
        rows = d.executor.evaluate(d.repo, d.job_id, generation, len(full), d.check,
                                   cut_margin=cut)
        if len(rows) != len(full):
            raise JobFailedError(f"generation {generation}: {len(rows)} evaluations stored for "
                                 f"{len(full)} candidates")
        for r in rows:
            if r.status == EVAL_FAILED:
                raise JobFailedError(
                    r.error or f"candidate {r.index} of generation {generation} failed")
        return [_stored_outcome(r) for r in rows]

    def _check_stored(self, generation: int, full: list[list[float]]) -> None:
        """Fail the job if a candidate stored before (by a driver that stopped) differs from
        the one asked again now. Rows created just now hold `full` itself: not read back."""
        d = self.driver
        stored = {r.index: r.params for r in d.repo.evaluations(d.job_id, generation)}
        for i, p in enumerate(full):
            params = stored.get(i)
            if params is not None and not np.allclose(params, p, rtol=0, atol=1e-12):
                raise JobFailedError(
                    f"generation {generation}: stored candidate {i} differs from the one "
                    "asked again after a restart (optimizer state not reproducible)")


def _stored_outcome(row: Any) -> EvalOutcome:
    """The EvalOutcome of a stored evaluation row (its details carry the error and the fall
    and task verdicts, `worker.candidates.outcome_fields`)."""
    d = row.details or {}
    return EvalOutcome(objective=float(row.objective), fell=bool(row.fell),
                       cpu_seconds=float(row.cpu_seconds or 0.0), error=d.get("error"),
                       fall_time=d.get("fall_time"), fall_direction=d.get("fall_direction"),
                       task_success=d.get("task_success"), cut=bool(d.get("cut", False)))


class StoreRunState:
    """`optim.loop.RunState` of a job: the optimizer pickled in each generation record."""

    def __init__(self, driver: JobDriver) -> None:
        self.driver = driver

    def restore(self) -> CmaOptimizer | None:
        d = self.driver
        latest = d.repo.latest_generation(d.job_id)
        if latest is None or latest.optimizer_state is None:
            return None
        log.info("job %s: resuming after generation %d", d.job_id, latest.iteration)
        return CmaOptimizer.loads(latest.optimizer_state)

    def save(self, opt: CmaOptimizer, generation: int, stats: GenerationStats,
             candidates: Any, wall_seconds: float) -> None:
        d = self.driver
        best_x = opt.best_x
        best_full = None if best_x is None else d.space.to_full(best_x)
        d.repo.record_generation(
            d.job_id,
            generation,
            best=stats.best,
            median=stats.median,
            worst=stats.worst,
            sigma=stats.sigma,
            best_so_far=stats.best_so_far,
            evaluations=stats.evaluations,
            wall_time=wall_seconds,
            candidates=[list(map(float, p)) for p in candidates],
            optimizer_state=opt.dumps(),
            best_params=None if best_full is None else list(map(float, best_full)),
        )
        if d.on_generation is not None:
            d.on_generation(generation)


def _with_start_sigma(spec: TaskSpec, start: JobStart | None) -> TaskSpec:
    """The spec whose optimizer starts the job: a start may set a smaller initial step
    (`sigma0`, box units) than the spec's, as a start from the library does."""
    if start is None or start.sigma0 is None:
        return spec
    opt = spec.optimize.model_copy(update={"sigma0": start.sigma0})
    return spec.model_copy(update={"optimize": opt})


class JobDriver:
    def __init__(
        self,
        repo: Repository,
        job_id: str,
        executor: GenerationExecutor,
        config: Settings,
        *,
        owner: str | None = None,
        shutdown: threading.Event | None = None,
        on_generation: Callable[[int], None] | None = None,
        cancels: CancelFlags | None = None,
    ) -> None:
        self.repo = repo
        self.job_id = job_id
        self.executor = executor
        self.config = config
        self.owner = owner or make_owner()
        self.shutdown = shutdown or threading.Event()
        self.on_generation = on_generation
        self.space: SearchSpace
        self._lease: _Lease | None = None
        #: The process's drivers share their cancel-flag reads (`CancelFlags`).
        self.cancels = cancels or CancelFlags(repo)
        #: (previous owner, its lease's expiry) when this driver took over a dead driver's job.
        self._took_over: tuple[str, Any] | None = None

    # -- interruption --------------------------------------------------------------------------
    def check(self, force: bool = False) -> None:
        """Raise a DriverInterruptError if the driver must stop now: DriverShutdownError,
        LeaseLostError, JobCancelledError.
        `force` (between generations): the job's cancel flag read now; otherwise as read for
        every job of this process at most `CANCEL_POLL_S` ago (`CancelFlags`)."""
        if self.shutdown.is_set():
            raise DriverShutdownError
        if self._lease is not None and self._lease.lost.is_set():
            raise LeaseLostError
        if (self.repo.cancel_requested(self.job_id) if force
                else self.cancels.requested(self.job_id)):
            raise JobCancelledError

    # -- main ----------------------------------------------------------------------------------
    def run(self) -> str | None:
        """Drive the job to its end; returns its final status, or None if this driver did not
        (could not) finish it (lease held elsewhere, shutdown, database unavailable)."""
        ttl = self.config.lease_seconds
        try:
            before = self.repo.get_job(self.job_id)
            if not self.repo.acquire_driver_lease(self.job_id, self.owner, ttl):
                return None
        except NotFound:
            return None
        if before.driver_owner not in (None, self.owner):  # its driver died: lease expired
            self._took_over = (before.driver_owner, before.lease_expires_at)
        self._lease = _Lease(self.repo, self.job_id, self.owner, ttl)
        self._lease.start()
        self.cancels.watch(self.job_id)
        try:
            return self._run()
        except JobCancelledError:
            return self._finish_status(CANCELLED)
        except DriverInterruptError as why:  # shutdown, lease lost: the job is left as it is
            log.info("job %s: driver stops (%s)", self.job_id, why)
            return None
        except (JobFailedError, EvaluationError) as err:
            log.error("job %s failed: %s", self.job_id, err)
            return self._finish_status(FAILED, error=str(err))
        except (SQLAlchemyError, StoreError) as err:
            log.warning("job %s: store error, leaving the job to be resumed: %s", self.job_id, err)
            return None
        except Exception as err:  # noqa: BLE001 - a bug must fail the job, not hang it
            log.exception("job %s: driver crashed", self.job_id)
            return self._finish_status(
                FAILED, error=f"internal error: {type(err).__name__}: {err}")
        finally:
            self.cancels.unwatch(self.job_id)
            self._lease.stop()
            with contextlib.suppress(Exception):
                self.repo.release_driver_lease(self.job_id, self.owner)

    def _finish_status(self, status: str, *, stop_rule: str | None = None,
                       error: str | None = None) -> str | None:
        job = self.repo.get_job(self.job_id)
        if job.terminal:
            return job.status
        if job.status == QUEUED and status not in (FAILED, CANCELLED):
            self.repo.set_job_status(self.job_id, RUNNING)
        self.repo.set_job_status(self.job_id, status, stop_rule=stop_rule, error=error)
        return status

    def _space(self, job: Any, spec: TaskSpec) -> SearchSpace:
        x0 = None if job.start is None else job.start.x0
        if job.basis_id is None:
            try:
                return SearchSpace.of(spec, None, x0)
            except Exception as err:  # noqa: BLE001 - a start of the wrong length
                raise JobFailedError(f"start: {err}") from None
        try:
            return SearchSpace.of(spec, basis_from_record(self.repo.get_basis(job.basis_id)),
                                  x0)
        except NotFound:
            raise JobFailedError(f"basis {job.basis_id!r} does not exist") from None
        except Exception as err:  # noqa: BLE001 - BasisError, bad stored box
            raise JobFailedError(f"basis {job.basis_id!r} cannot be used: {err}") from None

    def _run(self) -> str | None:
        job = self.repo.get_job(self.job_id)
        if job.terminal:
            return job.status
        try:  # parsed only if this process has not got it (the route of an embedded service has)
            canonical = job_spec(self.repo, self.job_id, job.spec_hash)
        except SpecError as err:
            raise JobFailedError(str(err)) from None
        spec = canonical.spec
        if job.cancel_requested:
            raise JobCancelledError
        if job.status == QUEUED:
            self.repo.set_job_status(self.job_id, RUNNING)
        self.space = self._space(job, spec)
        state = StoreRunState(self)
        opt = state.restore() or new_optimizer(
            _with_start_sigma(spec, job.start), self.space,
            int(job.seed if job.seed is not None else 0))
        if self._took_over is not None:
            self._log_takeover(opt.iterations)
        t_job = time.monotonic()
        evaluator = StoreEvaluator(self, opt.cut_margin if cut_allowed(spec) else None)
        stop_rule = run_generations(opt, self.space, evaluator, state)
        # A driver may have died after adding the entry or the result: the final evaluations
        # are stored, so asking them again costs no simulation.
        final = final_evaluation(opt, self.space, evaluator)
        if self.repo.job_cmrt(self.job_id) is None:
            self._add_to_library(job, spec, final)
        if self.repo.job_result(self.job_id) is None:
            wall = sum(g.wall_time for g in self.repo.generations(self.job_id))
            self.repo.set_job_result(self.job_id, result_of(
                canonical, opt, self.space, final, stop_rule=stop_rule,
                seed=int(job.seed if job.seed is not None else 0), wall_seconds=wall,
            ).to_dict())
        status = STOPPED if stop_rule in STOPPED_RULES else CONVERGED
        log.info("job %s: %s (%s) after %d generations, %.1f s", self.job_id, status, stop_rule,
                 opt.iterations, time.monotonic() - t_job)
        return self._finish_status(status, stop_rule=stop_rule)

    def _log_takeover(self, generation: int) -> None:
        owner, expired = self._took_over or (None, None)
        rows = self.repo.evaluations(self.job_id, generation)
        started = [r.index for r in rows if r.status == PENDING and r.attempts > 0]
        done = sum(r.status != PENDING for r in rows)
        ago = "" if expired is None else \
            f" {(datetime.now(UTC) - expired).total_seconds():.0f} s ago"
        log.info("job %s: taking over from driver %s whose lease expired%s; resuming at "
                 "generation %d: %d of its %d candidates already evaluated, %d started and "
                 "not finished, run again: %s", self.job_id, owner, ago, generation, done,
                 len(rows), len(started), started)

    def _add_to_library(self, job: Any, spec: TaskSpec, final: FinalEvaluation) -> None:
        """The library entry: the better of the best candidate and the flat spline (never
        worse than no anticipation); `winner` records which one it is."""
        params, out = final.chosen
        self.repo.add_cmrt(library_entry(
            spec, params, objective=float(out.objective), fell=bool(out.fell),
            objective_without=float(final.flat.objective), fell_without=bool(final.flat.fell),
            winner=final.winner, job_id=self.job_id, spec_document=job.spec))


__all__ = [
    "CANCEL_POLL_S",
    "FINAL_GENERATION",
    "STOPPED_RULES",
    "CancelFlags",
    "JobDriver",
    "StoreEvaluator",
    "StoreRunState",
    "make_owner",
]
