"""Families: submitting one (the request validated, the whole family admitted against the
job ceiling, then stored with its request's hash), the typed request of a stored family, kept
by that hash in the process's one spec cache (`optim.objective.SPECS`): a page polling a
family and the family driver parse it once per process, not at every poll or scan), and a
family's progress and document as the API serves them (`family_progress`: every run of the
plan with its job, the counts, and once done the members, basis and checks)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from application import admission
from application.characters import with_stored_character
from application.errors import InvalidRequest
from cmrt.canonical import document_hash
from cmrt.settings import Settings
from optim.family.plan import PROBES, PlannedRun, plan_runs
from optim.family.spec import FamilyError, FamilySpec, parse_family
from optim.objective import SPECS
from store import FamilyRecord, Repository


def submit_family(repo: Repository, settings: Settings, data: Any
                  ) -> tuple[FamilyRecord, admission.Budget, int]:
    """Validate a family request as it arrived (a parsed JSON body; a stored character its
    spec names put in first), admit it and store it; returns the family, its budget and the
    number of runs of its plan. InvalidRequest naming the field and the rule
    (`admission.BudgetExceeded` above the job ceiling)."""
    if isinstance(data, dict) and "spec" in data:
        data = {**data, "spec": with_stored_character(repo, data["spec"])}
    try:
        fs = parse_family(data)
        budget = admission.family_budget(fs, settings)
    except FamilyError as err:
        raise InvalidRequest(str(err)) from None
    doc = fs.to_dict()
    spec_hash = document_hash(doc)
    SPECS.typed(spec_hash, lambda: fs)  # the family drivers of this process find it parsed
    fam = repo.create_family(doc, family=fs.family, param=fs.param, spec_hash=spec_hash)
    return fam, budget, len(plan_runs(fs))


def family_spec(fam: FamilyRecord) -> FamilySpec:
    """The typed request of a stored family (parsed only if this process has not got it;
    FamilyError if it does not parse)."""
    return SPECS.typed(fam.spec_hash, lambda: parse_family(fam.spec))


def _run_row(run: PlannedRun, job: Any, job_url: Callable[[str], str]) -> dict[str, Any]:
    """A run of the plan and the state of its job (`not started` before it has one)."""
    return {
        "id": run.id, "kind": run.kind, "value": run.value, "warm_from": run.warm_from,
        "needs": list(run.needs), "job_id": None if job is None else job.id,
        "job_url": None if job is None else job_url(job.id),
        "status": "not started" if job is None else job.status,
        "best_objective": None if job is None else job.best_objective,
        "evaluations": 0 if job is None else job.evaluations,
        "start": None if job is None or job.start is None else job.start.origin,
    }


def _counts(runs: list[PlannedRun], jobs: Mapping[str, Any], probes_done: bool
            ) -> dict[str, int]:
    """The plan's runs, how many are done (the probes once evaluated), running, queued and
    not started."""
    done = sum(1 for r in runs if r.id in jobs and jobs[r.id].terminal)
    done += 1 if probes_done else 0
    return {"runs": len(runs), "done": done,
            "running": sum(1 for j in jobs.values() if j.status == "running"),
            "queued": sum(1 for j in jobs.values() if j.status == "queued"),
            "not_started": sum(1 for r in runs if r.id not in jobs and r.kind != PROBES)}


def family_progress(repo: Repository, fam: FamilyRecord, *, job_url: Callable[[str], str],
                    curves: bool = False) -> dict[str, Any]:
    """A stored family's request, every run of its plan with its job (`job_url(job id)`
    links it; `curves`: each run's [evaluations, best so far]), the counts, and once it is
    done the members, basis and checks of its report (None before)."""
    runs = plan_runs(family_spec(fam))
    jobs = repo.family_jobs(fam.id) if fam.runs else {}
    report = repo.family_report(fam.id) if fam.status == "done" else None
    rows = []
    for r in runs:
        if r.kind == PROBES:
            continue
        row = _run_row(r, jobs.get(r.id), job_url)
        if curves and r.id in jobs:
            row["curve"] = [[g.evaluations, g.best_so_far] for g in repo.generations(
                jobs[r.id].id)]
        rows.append(row)
    return {
        "spec": fam.spec, "runs": rows,
        "progress": _counts(runs, jobs, repo.family_probes(fam.id) is not None),
        "members": None if report is None else report["members"],
        "basis": None if report is None else report["basis"],
        "checks": None if report is None else report["checks"],
    }


__all__ = ["FamilySpec", "family_progress", "family_spec", "submit_family"]
