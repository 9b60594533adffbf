"""The job driver: the CMA-ES ask/tell loop of one job, run against the store.

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
(generation -1, same executor path), the CMRT goes into the library and the job ends `converged`
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
from typing import Any

import numpy as np
from sqlalchemy.exc import SQLAlchemyError

from optim.cmaes import CmaOptimizer, StopRules
from optim.pca import Basis
from optim.run import initial_point
from optim.spline import decode, flat_params, sample_curve
from sim.errors import SpecError
from sim.spec import TaskSpec, parse_spec
from store import NotFound, Repository, StoreError
from store.records import (
    CANCELLED,
    CONVERGED,
    EVAL_FAILED,
    FAILED,
    QUEUED,
    RUNNING,
    STOPPED,
)
from worker.config import WorkerConfig
from worker.executors import DriverInterruptError, GenerationExecutor, JobFailedError

log = logging.getLogger(__name__)

#: Generation number of the final re-evaluation (index 0: flat baseline, 1: best candidate).
FINAL_GENERATION = -1
#: Stopping rules that end a job `stopped` rather than `converged`.
STOPPED_RULES = frozenset({"max_evaluations"})


def make_owner() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def basis_from_record(rec: Any) -> Basis:
    """optim Basis from a store BasisRecord (box holds score_lo/score_hi, margin, cmrt)."""
    box = rec.box or {}
    return Basis(
        family=rec.family,
        k=rec.k,
        mean=np.asarray(rec.mean, dtype=float),
        components=np.asarray(rec.components, dtype=float),
        variance_explained=np.asarray(rec.variance_explained, dtype=float),
        members=list(rec.members),
        score_lo=np.asarray(box["score_lo"], dtype=float),
        score_hi=np.asarray(box["score_hi"], dtype=float),
        cmrt=dict(box.get("cmrt") or {}),
        margin=float(box.get("margin", 0.25)),
    )


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


class JobDriver:
    def __init__(
        self,
        repo: Repository,
        job_id: str,
        executor: GenerationExecutor,
        config: WorkerConfig,
        *,
        owner: str | None = None,
        shutdown: threading.Event | None = None,
        on_generation: Callable[[int], None] | None = None,
    ) -> None:
        self.repo = repo
        self.job_id = job_id
        self.executor = executor
        self.config = config
        self.owner = owner or make_owner()
        self.shutdown = shutdown or threading.Event()
        self.on_generation = on_generation
        self._lease: _Lease | None = None
        self._last_cancel_check = 0.0

    # -- interruption --------------------------------------------------------------------------
    def check(self, force: bool = False) -> None:
        """Raise DriverInterruptError if the driver must stop now (shutdown, lease lost, cancelled).
        The cancel flag is read from the store at most every 0.5 s unless `force`."""
        if self.shutdown.is_set():
            raise DriverInterruptError("shutdown")
        if self._lease is not None and self._lease.lost.is_set():
            raise DriverInterruptError("lease lost")
        now = time.monotonic()
        if force or now - self._last_cancel_check >= 0.5:
            self._last_cancel_check = now
            if self.repo.get_job(self.job_id).cancel_requested:
                raise DriverInterruptError("cancel")

    # -- main ----------------------------------------------------------------------------------
    def run(self) -> str | None:
        """Drive the job to its end; returns its final status, or None if this driver did not
        (could not) finish it (lease held elsewhere, shutdown, database unavailable)."""
        try:
            if not self.repo.acquire_driver_lease(self.job_id, self.owner, self.config.lease_ttl):
                return None
        except NotFound:
            return None
        self._lease = _Lease(self.repo, self.job_id, self.owner, self.config.lease_ttl)
        self._lease.start()
        try:
            return self._run()
        except DriverInterruptError as why:
            if str(why) == "cancel":
                return self._finish_status(CANCELLED)
            log.info("job %s: driver stops (%s)", self.job_id, why)
            return None
        except JobFailedError as err:
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

    def _problem(
        self, job: Any, spec: TaskSpec
    ) -> tuple[int, Callable[[np.ndarray], np.ndarray], Basis | None]:
        if job.basis_id is None:
            return spec.cmrt_dimension, lambda x: np.clip(np.asarray(x, float), 0.0, 1.0), None
        try:
            basis = basis_from_record(self.repo.get_basis(job.basis_id))
            basis.check_spec(spec)
        except NotFound:
            raise JobFailedError(f"basis {job.basis_id!r} does not exist") from None
        except Exception as err:  # noqa: BLE001 - BasisError, bad stored box
            raise JobFailedError(f"basis {job.basis_id!r} cannot be used: {err}") from None
        duration = spec.clip.duration
        return basis.k, lambda x: basis.decode(x, duration), basis

    def _run(self) -> str | None:
        job = self.repo.get_job(self.job_id)
        if job.terminal:
            return job.status
        try:
            spec = parse_spec(job.spec, f"job {self.job_id} spec")
        except SpecError as err:
            raise JobFailedError(str(err)) from None
        if job.cancel_requested:
            raise DriverInterruptError("cancel")
        if job.status == QUEUED:
            self.repo.set_job_status(self.job_id, RUNNING)
        dim, to_full, basis = self._problem(job, spec)

        latest = self.repo.latest_generation(self.job_id)
        if latest is not None and latest.optimizer_state is not None:
            opt = CmaOptimizer.loads(latest.optimizer_state)
            generation = latest.iteration + 1
            log.info("job %s: resuming after generation %d", self.job_id, latest.iteration)
        else:
            x0 = initial_point(spec, basis=basis)  # the same start rule as `cmrt optimize`
            opt = CmaOptimizer(
                dim,
                seed=int(job.seed if job.seed is not None else 0),
                x0=x0,
                sigma0=spec.optimize.sigma0,
                popsize=spec.optimize.popsize,
                rules=StopRules.from_config(spec.optimize),
            )
            generation = 0
        t_job = time.monotonic()

        stop_rule = opt.stop()
        while stop_rule is None:
            self.check(force=True)
            t0 = time.monotonic()
            xs = opt.ask()
            full = [to_full(x) for x in xs]
            self.repo.put_pending_evaluations(
                self.job_id, generation, [list(map(float, p)) for p in full])
            rows = self.executor.evaluate(
                self.repo, self.job_id, job.spec, generation, len(xs), self.check)
            self._check_rows(rows, generation, full)
            objectives = [r.objective for r in rows]
            if all((r.details or {}).get("error") for r in rows):
                raise JobFailedError(
                    f"every candidate of generation {generation} failed to evaluate; first error: "
                    f"{rows[0].details['error']}"
                )
            stats = opt.tell(xs, objectives)
            best_full = to_full(opt.best_x) if opt.best_x is not None else None
            self.repo.record_generation(
                self.job_id,
                generation,
                best=stats.best,
                median=stats.median,
                worst=stats.worst,
                sigma=stats.sigma,
                best_so_far=stats.best_so_far,
                evaluations=stats.evaluations,
                wall_time=time.monotonic() - t0,
                candidates=[list(map(float, p)) for p in full],
                optimizer_state=opt.dumps(),
                best_params=None if best_full is None else list(map(float, best_full)),
            )
            if self.on_generation is not None:
                self.on_generation(generation)
            generation += 1
            stop_rule = opt.stop()

        self.check(force=True)
        self._add_to_library(job, spec, opt, to_full, basis)
        status = STOPPED if stop_rule in STOPPED_RULES else CONVERGED
        log.info("job %s: %s (%s) after %d generations, %.1f s", self.job_id, status, stop_rule,
                 generation, time.monotonic() - t_job)
        return self._finish_status(status, stop_rule=stop_rule)

    def _check_rows(self, rows: list[Any], generation: int, full: list[np.ndarray]) -> None:
        if len(rows) != len(full):
            raise JobFailedError(f"generation {generation}: {len(rows)} evaluations stored for "
                            f"{len(full)} candidates")
        for r, p in zip(rows, full, strict=True):
            if r.status == EVAL_FAILED:
                raise JobFailedError(
                    r.error or f"candidate {r.index} of generation {generation} failed")
            if r.params is not None and not np.allclose(r.params, p, rtol=0, atol=1e-12):
                raise JobFailedError(
                    f"generation {generation}: stored candidate {r.index} differs from the one "
                    "asked again after a restart (optimizer state not reproducible)")

    def _library_entry(self) -> str | None:
        family = parse_spec(self.repo.get_job(self.job_id).spec).family_name
        offset = 0
        while True:
            items, total = self.repo.list_cmrts(family, limit=500, offset=offset)
            for c in items:
                if c.job_id == self.job_id:
                    return c.id
            offset += len(items)
            if not items or offset >= total:
                return None

    def _add_to_library(self, job: Any, spec: TaskSpec, opt: CmaOptimizer,
                        to_full: Callable[[np.ndarray], np.ndarray], basis: Basis | None) -> None:
        assert opt.best_x is not None
        if self._library_entry() is not None:  # a driver died after adding it: don't add twice
            return
        best_full = to_full(opt.best_x)
        base = flat_params(spec)
        self.repo.put_pending_evaluations(
            self.job_id, FINAL_GENERATION, [list(map(float, base)), list(map(float, best_full))])
        rows = self.executor.evaluate(
            self.repo, self.job_id, job.spec, FINAL_GENERATION, 2, self.check)
        for r, label in zip(rows, ("baseline (flat spline)", "best CMRT"), strict=True):
            if r.status == EVAL_FAILED or (r.details or {}).get("error"):
                raise JobFailedError(f"final evaluation of the {label} failed: "
                                f"{r.error or r.details.get('error')}")
        base_row, best_row = rows
        spline = decode(spec, best_full)
        values: list[Any] = [float(v) for v in spline.values]
        if spline.vertical_values is not None:
            values = [[float(a), float(b)]
                      for a, b in zip(spline.values, spline.vertical_values, strict=True)]
        self.repo.add_cmrt(
            family=spec.family_name,
            character=spec.character.model_dump(mode="json"),
            task_parameters=spec.task_parameters(),
            preparation=spec.clip.preparation,
            duration=spec.clip.duration,
            decay=spec.clip.decay,
            params=[float(v) for v in best_full],
            knots=[float(v) for v in spline.knot_times],
            values=values,
            curve=sample_curve(spline),
            objective=float(best_row.objective),
            objective_without=float(base_row.objective),
            fell=bool(best_row.fell),
            fell_without=bool(base_row.fell),
            job_id=self.job_id,
            spec=job.spec,
        )
