"""The family driver: the service's driver of the family state machine
(`optim.family.machine`), whose runs are ordinary jobs of the service.

`FamilyDriver.advance(family_id)` is one idempotent step, made every scan by the runner of
every unfinished family: it reads the family's state from the store and asks
`optim.family.machine.next_actions`, then carries the actions out:

    the state: the family's request and its runs' jobs; a job that failed or was cancelled
        (not by the family) is a failed run (its error the reason); the finished jobs'
        result documents are the results (run id -> result); the probes' outcomes once kept
        with the family, or once the driver's probe thread has them (then kept)
    Cancel -> cancel every unfinished job of the family; `cancelled` once none runs
    Fail -> cancel the others, the family fails naming the run and its job
    StartRun -> its job, submitted through `application.jobs.submit_job` and created at most
        once (`add_family_run`): the run's spec and seed, its start point (a `JobStart`) and,
        for a reduced run, the leave-one-out basis stored as a PCA basis; the job is handed
        to `submit` so a driver starts at once
    EvaluateProbes -> handed to a thread of the driver's own, evaluated there in a process of
        their own; a later step picks their outcomes up (the step never waits for them, so no
        other family's step waits either)
    Finish -> the family's document, made now (`optim.family.report.family_report`, with the
        family's id and jobs), kept as its report; `done`

A step reads the family's state in one store call (`family_scan`).

The same plan, starts, seeds and stopping rules as `cmrt family run` (optim.family_run), and
a job's result document is the command line's (`optim.run.result_of`), so a family run here
gives the same members and checks as the command line with the same seeds. Nothing lives only
in memory: a driver (or API) killed at any point is replaced by the next scan, which finds the
jobs already made and resumes them like any job; probes under way in a process that died are
evaluated again (the same points, the same outcomes).
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from application.bases import store_basis
from application.errors import ApplicationError
from application.families import family_spec
from application.jobs import submit_job
from cmrt.settings import Settings
from optim.errors import EvaluationError, OptimError
from optim.executors import Executor, PoolExecutor
from optim.family import machine
from optim.family.plan import PlannedRun, RunStart
from optim.family.report import family_report
from optim.family.spec import FamilyError, FamilySpec, member_objective
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult
from sim.spec import canonical_spec
from store import FamilyScan, Repository
from store.records import CANCELLED, FAILED, FAMILY_DONE, JobStart

log = logging.getLogger(__name__)


class FamilyDriver:
    """Advances families (see module docstring). `submit(job_id)` starts a job's driver now
    (the scan would find it later anyway); the probes are evaluated in a process of the
    driver's own (a simulation never holds this process' interpreter), called from a thread of
    the driver's own so that `advance` never waits for a simulation. `settings`:
    the server's, which the runs' jobs are admitted under as any job is."""

    def __init__(
        self,
        repo: Repository,
        settings: Settings,
        *,
        submit: Callable[[str], Any] | None = None,
    ) -> None:
        self.repo, self.settings = repo, settings
        self.submit = submit or (lambda _job_id: None)
        self._probe_executor: Executor | None = None
        self._lock = threading.Lock()
        #: Parsed results of finished runs, per family (a finished job's result never changes).
        self._results: dict[str, dict[str, OptimizationResult]] = {}
        #: Probes under way, per family: their outcomes by value once evaluated.
        self._probing: dict[str, cf.Future] = {}
        self._probe_thread: cf.ThreadPoolExecutor | None = None
        self._closed = False

    def close(self) -> None:
        """Stop evaluating probes (an evaluation under way ends with its process; a later
        driver evaluates them again) and release the probes' process."""
        with self._lock:
            self._closed = True
            for fut in self._probing.values():
                fut.cancel()
            self._probing.clear()
            thread, self._probe_thread = self._probe_thread, None
        if thread is not None:
            thread.shutdown(wait=False, cancel_futures=True)
        with self._lock:
            if self._probe_executor is not None:
                self._probe_executor.close()
                self._probe_executor = None

    def _probes_executor(self) -> Executor:
        with self._lock:  # the probe thread asks; close() may run meanwhile
            if self._closed:
                raise EvaluationError("the family driver is closed")
            if self._probe_executor is None:
                self._probe_executor = PoolExecutor(1)
            return self._probe_executor

    def advance(self, family_id: str) -> str:
        """One step of the family (see module docstring); returns its status after it. A
        domain error of the plan's arithmetic (a basis or an interpolation that cannot be
        made from these members) or of the probes' evaluation fails the family with its
        message: the same members would give it again at every step; so does a run's job
        the application refuses."""
        try:
            return self._advance(family_id)
        except (OptimError, ApplicationError) as err:
            log.error("family %s: %s", family_id, err)
            with self._lock:
                self._forget(family_id)
                self._cancel_jobs(self.repo.family_jobs(family_id).values())
                return self.repo.finish_family(family_id, FAILED, error=str(err)).status

    def _advance(self, family_id: str) -> str:
        with self._lock:  # one step at a time in this process; other processes may race
            scan = self.repo.family_scan(family_id, self._results.get(family_id, {}).keys())
            fam = scan.family
            if fam.terminal:
                self._forget(family_id)
                return fam.status
            try:
                fs = family_spec(fam)
            except FamilyError as err:
                self._forget(family_id)
                return self.repo.finish_family(family_id, FAILED, error=str(err)).status
            state = self._state(family_id, scan)
            for action in machine.next_actions(fs, state):
                status = self._carry_out(family_id, fs, scan.jobs, state, action)
                if status is not None:
                    return status
            return fam.status

    def _state(self, family_id: str, scan: FamilyScan) -> machine.FamilyState:
        """The family's state from its jobs, their result documents and its probes."""
        jobs, cancel_requested = scan.jobs, scan.family.cancel_requested
        failed = {rid: job.error or job.status for rid, job in jobs.items()
                  if job.status in (FAILED, CANCELLED)}
        if cancel_requested or failed:  # it ends now: its results and probes are not used
            return machine.FamilyState(running=frozenset(jobs.keys() - failed.keys()),
                                       failed=failed, cancel_requested=cancel_requested)
        cache = self._results.setdefault(family_id, {})
        for rid, doc in scan.results.items():  # a finished job's result never changes
            cache[rid] = OptimizationResult.from_dict(doc, f"run {rid}")
        results = dict(cache)
        probes = None if scan.probes is None else {
            float(v): EvalOutcome.from_dict(o) for v, o in scan.probes}
        if probes is None:
            probes = self._evaluated_probes(family_id)
        return machine.FamilyState(results, frozenset(jobs.keys() - results.keys()), probes,
                                   family_id in self._probing)

    def _carry_out(self, family_id: str, fs: FamilySpec, jobs: dict[str, Any],
                   state: machine.FamilyState, action: machine.Action) -> str | None:
        """One action of the state machine; the family's status when the step ends here."""
        if isinstance(action, machine.StartRun):
            self._start(family_id, fs, action.run, action.start, state.results)
        elif isinstance(action, machine.EvaluateProbes):
            self._hand_probes(family_id, fs, action.points)
        elif isinstance(action, machine.Finish):
            self._forget(family_id)
            report = {**family_report(fs, state.results, state.probes), "family_id": family_id,
                      "jobs": {k: j.id for k, j in jobs.items()}}
            return self.repo.finish_family(family_id, FAMILY_DONE, report=report).status
        elif isinstance(action, machine.Fail):
            job = jobs[action.run_id]
            log.error("family %s: run %s (job %s) %s", family_id, action.run_id, job.id,
                      action.reason)
            self._cancel_jobs([jobs[r] for r in action.stop])
            self._forget(family_id)
            return self.repo.finish_family(
                family_id, FAILED, error=f"run {action.run_id} (job {job.id}): {action.reason}"
            ).status
        elif isinstance(action, machine.Cancel):
            live = self._cancel_jobs([jobs[r] for r in action.stop])
            if any(not self.repo.get_job(j.id).terminal for j in live):
                return self.repo.get_family(family_id).status  # their drivers stop them
            self._forget(family_id)
            return self.repo.finish_family(family_id, CANCELLED).status
        return None

    # -- pieces --------------------------------------------------------------------------------
    def _forget(self, family_id: str) -> None:
        """Drop what this process keeps of a family that ends (its probes' evaluation too,
        should it still be queued)."""
        self._results.pop(family_id, None)
        fut = self._probing.pop(family_id, None)
        if fut is not None:
            fut.cancel()

    def _cancel_jobs(self, jobs: Iterable[Any]) -> list[Any]:
        live = [j for j in jobs if not j.terminal]
        for j in live:
            self.repo.request_cancel(j.id)
        return live

    def _start(self, family_id: str, fs: FamilySpec, run: PlannedRun, st: RunStart,
               results: Mapping[str, OptimizationResult]) -> None:
        basis_id = None if st.basis is None else store_basis(
            self.repo, st.basis, fs.family,
            [f"{family_id}/{rid}" for rid in sorted(results) if rid != run.id])
        start = "cold" if st.x0 is None else JobStart(st.start, tuple(
            float(v) for v in np.asarray(st.x0)))
        job, _ = submit_job(self.repo, self.settings, canonical_spec(st.spec), seed=fs.seed,
                            basis_id=basis_id, start=start, run=(family_id, run.id))
        log.info("family %s: run %s is job %s%s", family_id, run.id, job.id,
                 f" (from {st.start})" if st.start != "flat" else "")
        if not job.terminal:
            self.submit(job.id)

    def _hand_probes(self, family_id: str, fs: FamilySpec,
                     points: Sequence[tuple[float, np.ndarray]]) -> None:
        """Hand the probes' evaluation to the probe thread; a later step picks it up."""
        if self._probe_thread is None:
            self._probe_thread = cf.ThreadPoolExecutor(max_workers=1,
                                                       thread_name_prefix="family-probes")
        self._probing[family_id] = self._probe_thread.submit(self._evaluate_probes, fs,
                                                             list(points))
        log.info("family %s: evaluating %d probes", family_id, len(points))

    def _evaluated_probes(self, family_id: str) -> dict[float, EvalOutcome] | None:
        """The probes' outcomes once the probe thread has them (then kept with the family),
        else None. An evaluation that failed is raised here, as it would have been in this
        step."""
        fut = self._probing.get(family_id)
        if fut is None or not fut.done():
            return None
        del self._probing[family_id]
        got = fut.result()  # an error fails the family (advance) or is retried next scan
        self.repo.set_family_probes(family_id, [[v, o.to_dict()] for v, o in sorted(got.items())])
        return got

    def _evaluate_probes(self, fs: FamilySpec,
                         points: list[tuple[float, np.ndarray]]) -> dict[float, EvalOutcome]:
        """In the probe thread: each probe's outcome, evaluated through the probe executor."""
        ex = self._probes_executor()
        return {v: ex.map(member_objective(fs, v), [params])[0] for v, params in points}


__all__ = ["FamilyDriver"]
