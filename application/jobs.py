"""Jobs: submitting one (its basis, budget and library start, then the stored job with its
spec's hash) and the typed spec of a stored job, found by that hash in the process's one spec
cache (`optim.objective.SPECS`), so that a process parses a job's spec at most once."""

from __future__ import annotations

from application import admission
from application.bases import job_basis
from application.library import library_start
from cmrt.defaults import DEFAULT_SEED
from cmrt.settings import Settings
from optim.objective import SPECS
from sim.spec import CanonicalSpec, stored_spec
from store import JobRecord, JobStart, Repository

#: `start`: "library" starts from the library's CMRT at the spec's task parameters when it has
#: one (interpolated between neighbours, or stored there), else the flat spline; "cold" always
#: from the flat spline.
START_CHOICES = ("library", "cold")


def submit_job(repo: Repository, settings: Settings, spec: CanonicalSpec, *,
               seed: int = DEFAULT_SEED, basis_id: str | None = None,
               start: str | JobStart = "library", run: tuple[str, str] | None = None
               ) -> tuple[JobRecord, admission.Budget]:
    """Admit and store a new job of `spec` (canonicalised where it entered): the basis it
    names must fit the spec (`bases.UnusableBasisError`), its budget stay under the server's
    ceiling (`admission.BudgetExceeded`); it starts from the library unless `start` is
    "cold" or it searches a basis. `run`: (family id, run id) for the job of a family's run,
    created at most once (the run's job if it has one already). The spec is kept in this
    process' cache, so that a driver here finds it without parsing."""
    typed = SPECS.put(spec).spec
    k = None if basis_id is None else job_basis(repo, basis_id, typed).k
    budget = admission.check(typed, settings, dimension=k)
    if isinstance(start, JobStart):
        warm: JobStart | None = start
    else:
        warm = library_start(repo, typed) if start == "library" and basis_id is None else None
    fields = {"spec_hash": spec.hash, "name": typed.name, "family": typed.family_name,
              "task": typed.task_type, "seed": seed, "basis_id": basis_id, "start": warm}
    if run is None:
        return repo.create_job(spec.document, **fields), budget
    return repo.add_family_run(run[0], run[1], spec.document, **fields), budget


def stored_job_spec(job: JobRecord) -> CanonicalSpec:
    """The typed spec of a stored job (parsed only if this process has not got it)."""
    return SPECS.stored(job.spec, job.spec_hash, f"job {job.id} spec")


def job_spec(repo: Repository, job_id: str, spec_hash: str | None = None) -> CanonicalSpec:
    """The typed spec of job `job_id`; with its `spec_hash` known the store is read only on a
    miss of the cache. SpecError if the stored spec does not parse; NotFound."""
    if spec_hash is None:
        return stored_job_spec(repo.get_job(job_id))
    return SPECS.get(spec_hash, lambda: stored_spec(repo.get_job(job_id).spec, spec_hash,
                                                    f"job {job_id} spec"))


__all__ = ["START_CHOICES", "job_spec", "stored_job_spec", "submit_job"]
