"""Jobs: a job request checked once into its command (`SubmitJob`), submitting it (its basis,
budget and library start, then the stored job with its spec's hash: `AcceptedJob`), a job's
best candidate as a curve, cancelling one, and the typed spec of a stored job, found by that
hash in the process's one spec cache (`optim.objective.SPECS`), so that a process parses a
job's spec at most once."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from application import admission
from application.bases import job_basis
from application.characters import with_stored_character
from application.errors import InvalidRequest, RequestConflict
from application.library import library_start
from cmrt.defaults import DEFAULT_SEED
from cmrt.settings import Settings
from optim.objective import SPECS
from optim.spline import decode, sample_curve
from sim.errors import SpecError
from sim.spec import CanonicalSpec, TaskSpec, parse_canonical, stored_spec
from store import JobRecord, JobStart, Repository

#: `start`: "library" starts from the library's CMRT at the spec's task parameters when it has
#: one (interpolated between neighbours, or stored there), else the flat spline; "cold" always
#: from the flat spline.
START_CHOICES = ("library", "cold")
#: Largest seed of a job (CMA-ES takes a 31-bit seed).
MAX_SEED = 2**31 - 1
#: Longest basis id a request may name.
MAX_BASIS_ID = 64
#: The fields of a job request (`SubmitJob.parse`).
REQUEST_FIELDS = ("spec", "seed", "basis", "start")
#: What a body without its `spec` is told to send.
SPEC_REQUIRED = ('spec: required; a job request is {"spec": ...} (a bare task spec as the '
                 'whole body is no longer accepted: send it as `spec`)')


@dataclass(frozen=True)
class SubmitJob:
    """Optimise `spec` (canonicalised where it entered) with CMA-ES seed `seed`, in the PCA
    basis `basis` when one is named, starting as `start` says (START_CHOICES)."""

    spec: CanonicalSpec
    seed: int = DEFAULT_SEED
    basis: str | None = None
    start: str = "library"

    @classmethod
    def parse(cls, data: Any, repo: Repository | None = None) -> SubmitJob:
        """A job request `{"spec": {...}, "seed": n, "basis": "<basis id>", "start": how}`
        checked whole (InvalidRequest naming the field and the rule); with `repo`, a stored
        character the spec names has its definition put in first."""
        if not isinstance(data, dict):
            raise InvalidRequest('body: a job request must be a mapping {"spec": ...}, got '
                                 f"{type(data).__name__}")
        if "spec" not in data:
            raise InvalidRequest(SPEC_REQUIRED)
        extra = set(data) - set(REQUEST_FIELDS)
        if extra:
            raise InvalidRequest(f"{sorted(extra)[0]}: unknown field (allowed: "
                                 f"{', '.join(REQUEST_FIELDS)})")
        seed, basis, start = data.get("seed"), data.get("basis"), data.get("start")
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)
                                 or not 0 <= seed <= MAX_SEED):
            raise InvalidRequest("seed: must be an integer in [0, 2^31)")
        if basis is not None and (not isinstance(basis, str) or len(basis) > MAX_BASIS_ID):
            raise InvalidRequest("basis: must be a basis id (string)")
        if start is not None and start not in START_CHOICES:
            raise InvalidRequest(f"start: must be one of {', '.join(START_CHOICES)}")
        spec = data["spec"] if repo is None else with_stored_character(repo, data["spec"])
        try:  # the one parse: the drivers of this process find it by its hash (SPECS)
            canonical = parse_canonical(spec, "spec")
        except SpecError as err:
            raise InvalidRequest(str(err)) from None
        return cls(canonical, DEFAULT_SEED if seed is None else seed, basis,
                   "library" if start is None else start)


@dataclass(frozen=True)
class AcceptedJob:
    """A job stored and queued, and the most it may cost."""

    job: JobRecord
    budget: admission.Budget


@dataclass(frozen=True)
class BestCurve:
    """A job's best candidate decoded on its spec: knot times, values (and vertical values
    of a 2-D CMRT) and the curve sampled (`optim.spline.sample_curve`)."""

    knot_times: list[float]
    values: list[float]
    vertical_values: list[float] | None
    curve: dict[str, list[float]]


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


def submit(repo: Repository, settings: Settings, cmd: SubmitJob) -> AcceptedJob:
    """Admit and store the job `cmd` asks for (the refusals of `submit_job`)."""
    job, budget = submit_job(repo, settings, cmd.spec, seed=cmd.seed, basis_id=cmd.basis,
                             start=cmd.start)
    return AcceptedJob(job, budget)


def submit_request(repo: Repository, settings: Settings, data: Any) -> AcceptedJob:
    """A job request as it arrived (a parsed JSON body) checked (`SubmitJob.parse`, a stored
    character put in), admitted and stored."""
    return submit(repo, settings, SubmitJob.parse(data, repo))


def best_curve(job: JobRecord) -> BestCurve | None:
    """The best candidate of `job` so far (or finished with) as a curve on the job's spec;
    None until a generation has been recorded."""
    if job.best_params is None:
        return None
    spline = decode(stored_job_spec(job).spec, job.best_params)
    vertical = spline.vertical_values
    return BestCurve([float(v) for v in spline.knot_times], [float(v) for v in spline.values],
                     None if vertical is None else [float(v) for v in vertical],
                     sample_curve(spline))


def cancel_job(repo: Repository, job_id: str) -> JobRecord:
    """Ask the drivers to cancel job `job_id` (NotFound; RequestConflict once it finished)."""
    job = repo.get_job(job_id)
    if job.terminal:
        raise RequestConflict(f"job {job_id} already finished ({job.status})")
    return repo.request_cancel(job_id)


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


__all__ = ["MAX_SEED", "REQUEST_FIELDS", "SPEC_REQUIRED", "START_CHOICES", "BestCurve",
           "AcceptedJob", "SubmitJob", "TaskSpec", "best_curve", "cancel_job", "job_spec",
           "stored_job_spec", "submit", "submit_job", "submit_request"]
