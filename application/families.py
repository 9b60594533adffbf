"""Families: a family request checked once into its command (`SubmitFamily`), submitting it
(the whole family admitted against the job ceiling, then stored with its request's hash:
`AcceptedFamily`), the typed request of a stored family, kept by that hash in the process's
one spec cache (`optim.objective.SPECS`: a page polling a family and the family driver parse
it once per process, not at every poll or scan), and a family's state as the API serves it
(`family_detail`: its request, every run of the plan with its job (`FamilyRunOut`), the
counts (`FamilyProgress`), and once done the members, basis and checks)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, Field

from application import admission
from application.characters import request_with_stored_character
from application.errors import InvalidRequest
from cmrt.canonical import document_hash
from cmrt.settings import Settings
from optim.family.plan import PROBES, PlannedRun, plan_runs
from optim.family.spec import FamilyError, FamilySpec, parse_family
from optim.objective import SPECS
from store import FamilyRecord, JobRecord, Repository


@dataclass(frozen=True)
class SubmitFamily:
    """Grow the family `spec` asks for (docs/families.md): one run per value of its plan."""

    spec: FamilySpec

    @classmethod
    def parse(cls, data: Any, repo: Repository | None = None) -> SubmitFamily:
        """A family request as it arrived (a parsed JSON body) checked whole (InvalidRequest
        naming the field and the rule); with `repo`, a stored character its spec names has its
        definition put in first."""
        if repo is not None:
            data = request_with_stored_character(repo, data)
        try:
            return cls(parse_family(data))
        except FamilyError as err:
            raise InvalidRequest(str(err)) from None


@dataclass(frozen=True)
class AcceptedFamily:
    """A family stored (its driver starts its runs), the most it may cost and the number of
    runs of its plan."""

    family: FamilyRecord
    budget: admission.Budget
    runs: int


class FamilyRunOut(BaseModel):
    """One run of a family's plan and the job that runs it (null until it is started)."""

    id: str
    kind: str
    value: float | None
    warm_from: str | None = Field(description="the run whose optimum starts this one (null: "
                                              "the flat spline)")
    needs: list[str] = Field(description="runs that must be finished first")
    job_id: str | None
    job_url: str | None
    status: str
    best_objective: float | None
    evaluations: int
    start: str | None = Field(description="where the run's search started (the job's "
                                          "`start.from`)")
    curve: list[list[float]] | None = Field(
        None, description="[evaluations, best so far] per generation; only with curves=true")


class FamilyProgress(BaseModel):
    runs: int
    done: int
    running: int
    queued: int
    not_started: int


@dataclass(frozen=True)
class FamilyDetail:
    """A stored family's request, every run of its plan with its job, the counts, and once it
    is done the members, basis and checks of its report (None before)."""

    spec: dict[str, Any]
    runs: list[FamilyRunOut]
    progress: FamilyProgress
    members: list[dict[str, Any]] | None
    basis: dict[str, Any] | None
    checks: dict[str, Any] | None


def submit_family(repo: Repository, settings: Settings, cmd: SubmitFamily) -> AcceptedFamily:
    """Admit the family `cmd` asks for as a whole (InvalidRequest naming the field and the
    rule; `admission.BudgetExceeded` above the job ceiling) and store it."""
    fs = cmd.spec
    try:
        budget = admission.family_budget(fs, settings)
    except FamilyError as err:
        raise InvalidRequest(str(err)) from None
    doc = fs.to_dict()
    spec_hash = document_hash(doc)
    SPECS.typed(spec_hash, lambda: fs)  # the family drivers of this process find it parsed
    fam = repo.create_family(doc, family=fs.family, param=fs.param, spec_hash=spec_hash)
    return AcceptedFamily(fam, budget, len(plan_runs(fs)))


def submit_family_request(repo: Repository, settings: Settings, data: Any) -> AcceptedFamily:
    """A family request as it arrived (a parsed JSON body) checked (`SubmitFamily.parse`, a
    stored character put in), admitted and stored."""
    return submit_family(repo, settings, SubmitFamily.parse(data, repo))


def family_spec(fam: FamilyRecord) -> FamilySpec:
    """The typed request of a stored family (parsed only if this process has not got it;
    FamilyError if it does not parse)."""
    return SPECS.typed(fam.spec_hash, lambda: parse_family(fam.spec))


def _run_out(run: PlannedRun, job: JobRecord | None, job_url: Callable[[str], str],
             curve: list[list[float]] | None) -> FamilyRunOut:
    """A run of the plan and the state of its job (`not started` before it has one); its
    curve only when one was asked for (otherwise the field is left out of the answer)."""
    extra = {} if curve is None else {"curve": curve}
    return FamilyRunOut(
        id=run.id, kind=run.kind, value=run.value, warm_from=run.warm_from,
        needs=list(run.needs), job_id=None if job is None else job.id,
        job_url=None if job is None else job_url(job.id),
        status="not started" if job is None else job.status,
        best_objective=None if job is None else job.best_objective,
        evaluations=0 if job is None else job.evaluations,
        start=None if job is None or job.start is None else job.start.origin, **extra)


def _counts(runs: list[PlannedRun], jobs: Mapping[str, JobRecord], probes_done: bool
            ) -> FamilyProgress:
    """The plan's runs, how many are done (the probes once evaluated), running, queued and
    not started."""
    done = sum(1 for r in runs if r.id in jobs and jobs[r.id].terminal)
    done += 1 if probes_done else 0
    return FamilyProgress(
        runs=len(runs), done=done,
        running=sum(1 for j in jobs.values() if j.status == "running"),
        queued=sum(1 for j in jobs.values() if j.status == "queued"),
        not_started=sum(1 for r in runs if r.id not in jobs and r.kind != PROBES))


def family_detail(repo: Repository, fam: FamilyRecord, *, job_url: Callable[[str], str],
                  curves: bool = False) -> FamilyDetail:
    """A stored family's request, every run of its plan with its job (`job_url(job id)`
    links it; `curves`: each started run's [evaluations, best so far]), the counts, and once
    it is done the members, basis and checks of its report."""
    runs = plan_runs(family_spec(fam))
    jobs = repo.family_jobs(fam.id) if fam.runs else {}
    report = repo.family_report(fam.id) if fam.status == "done" else None
    rows = []
    for r in runs:
        if r.kind == PROBES:
            continue
        job = jobs.get(r.id)
        curve = None if not curves or job is None else [
            [g.evaluations, g.best_so_far] for g in repo.generations(job.id)]
        rows.append(_run_out(r, job, job_url, curve))
    return FamilyDetail(
        spec=fam.spec, runs=rows,
        progress=_counts(runs, jobs, repo.family_probes(fam.id) is not None),
        members=None if report is None else report["members"],
        basis=None if report is None else report["basis"],
        checks=None if report is None else report["checks"])


__all__ = ["AcceptedFamily", "FamilyDetail", "FamilyProgress", "FamilyRunOut", "FamilySpec",
           "SubmitFamily", "family_detail", "family_spec", "submit_family",
           "submit_family_request"]
