"""`/jobs`: submit a task spec for optimisation, follow it, cancel it."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse

from application import jobs
from application.admission import BudgetExceeded
from application.bases import UnusableBasisError
from application.characters import with_stored_character
from application.jobs import START_CHOICES
from cmrt.defaults import DEFAULT_SEED
from optim.spline import decode, sample_curve
from service import schemas
from service.body import read_json
from service.deps import MAX_OFFSET, RepoDep, ServicesDep, url_for
from service.errors import HttpError
from service.openapi import error_responses, json_body
from service.views import generation_out, job_cmrt_id, job_out
from sim.errors import SpecError
from sim.spec import parse_canonical
from store.records import JOB_STATUSES

router = APIRouter(prefix="/jobs", tags=["jobs"])

#: Largest seed of a job (CMA-ES takes a 31-bit seed).
MAX_SEED = 2**31 - 1
_ENVELOPE_KEYS = {"spec", "seed", "basis", "start"}
JobStatus = Literal[JOB_STATUSES]  # type: ignore[valid-type]


def _envelope(data: Any, seed: int | None, basis: str | None, start: str
              ) -> tuple[Any, int | None, str | None, str]:
    """Split `{"spec": ..., "seed": n, "basis": id, "start": how}` (the body values win over
    the query's)."""
    if not (isinstance(data, dict) and "spec" in data):
        return data, seed, basis, start
    extra = set(data) - _ENVELOPE_KEYS
    if extra:
        raise HttpError(422, f"{sorted(extra)[0]}: unknown field (allowed: spec, seed, basis, "
                            "start)")
    env_seed, env_basis = data.get("seed"), data.get("basis")
    if env_seed is not None and (not isinstance(env_seed, int) or isinstance(env_seed, bool)
                                 or not 0 <= env_seed <= MAX_SEED):
        raise HttpError(422, "seed: must be an integer in [0, 2^31)")
    if env_basis is not None and (not isinstance(env_basis, str) or len(env_basis) > 64):
        raise HttpError(422, "basis: must be a basis id (string)")
    env_start = data.get("start")
    if env_start is not None and env_start not in START_CHOICES:
        raise HttpError(422, f"start: must be one of {', '.join(START_CHOICES)}")
    return (data["spec"], env_seed if env_seed is not None else seed,
            env_basis if env_basis is not None else basis,
            env_start if env_start is not None else start)


@router.post("", status_code=202, response_model=schemas.JobAccepted,
             summary="Submit a task spec for optimisation",
             openapi_extra=json_body(
                 schemas.JobRequest, example={"spec": schemas.JOB_EXAMPLE, "seed": 1},
                 description="the envelope `{spec, seed, basis, start}` (a bare task spec as "
                             "the whole body is accepted too, as earlier clients send it)"),
             responses=error_responses(400, 413, 415, 422))
async def submit_job(
    request: Request,
    svc: ServicesDep,
    seed: Annotated[int | None, Query(ge=0, le=MAX_SEED)] = None,
    basis: Annotated[str | None, Query(max_length=64)] = None,
    start: Annotated[Literal["library", "cold"], Query(
        description="library: start from the library's CMRT at these task parameters when "
                    "there is one (interpolated or stored; the job's `start` says which); "
                    "cold: from the flat spline")] = "library",
) -> JSONResponse:
    """Body: `{"spec": {...}, "seed": n, "basis": "<basis id>", "start": "library"}`, the
    spec as the CLI's YAML/JSON files (a bare spec as the whole body is accepted too; the
    query's seed, basis and start apply then). 202 with the job's URL in `Location`."""
    data = await read_json(request, svc.settings.max_body_bytes)
    data, seed, basis, start = _envelope(data, seed, basis, start)
    data = with_stored_character(svc.repo, data)  # a stored character named: its definition
    try:  # the one parse: the drivers of this process find it by its hash (optim.objective)
        canonical = parse_canonical(data, "spec")
    except SpecError as err:
        raise HttpError(422, str(err)) from None
    try:  # its basis, its budget against the server's ceiling, its start (application.jobs)
        job, budget = jobs.submit_job(svc.repo, svc.settings, canonical,
                                      seed=DEFAULT_SEED if seed is None else seed, basis_id=basis,
                                      start=start)
    except (UnusableBasisError, BudgetExceeded) as err:
        raise HttpError(422, str(err)) from None
    if svc.run_drivers:
        svc.runner.submit(job.id)
    url = url_for(request, "get_job", job_id=job.id)
    return JSONResponse({"id": job.id, "url": url, "status": job.status,
                         "budget": budget.to_dict()},
                        status_code=202, headers={"Location": url})


@router.get("", response_model=schemas.JobPage, summary="List jobs",
            responses=error_responses(422))
def list_jobs(
    request: Request,
    repo: RepoDep,
    status: JobStatus | None = None,
    family: Annotated[str | None, Query(max_length=100)] = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> dict[str, Any]:
    items, total = repo.list_jobs(status=status, family=family, limit=limit, offset=offset)
    return {"items": [job_out(j, request) for j in items], "total": total,
            "limit": limit, "offset": offset}


@router.get("/{job_id}", response_model=schemas.JobOut, summary="One job",
            responses=error_responses(404))
def get_job(job_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    job = repo.get_job(job_id)
    out = job_out(job, request, job_cmrt_id(repo, job))
    out["spec"] = job.spec
    out["fingerprints"] = repo.evaluation_fingerprints(job_id)
    if (job.spec.get("optimize") or {}).get("robust"):
        out["robust"] = (repo.job_result(job_id) or {}).get("robust")
    return out


@router.get("/{job_id}/generations", response_model=schemas.GenerationPage,
            summary="Generations after N (incremental polling)",
            responses=error_responses(404))
def job_generations(
    job_id: str,
    repo: RepoDep,
    after: Annotated[int, Query(ge=-1, le=MAX_OFFSET,
                                description="iteration; -1 for all")] = -1,
    limit: Annotated[int, Query(ge=1, le=1000)] = 1000,
) -> dict[str, Any]:
    job = repo.get_job(job_id)
    gens = repo.generations(job_id, after=after)[:limit]
    return {"job_id": job_id, "status": job.status, "after": after,
            "last": gens[-1].iteration if gens else after,
            "generations": [generation_out(g) for g in gens]}


@router.get("/{job_id}/evaluations", response_model=schemas.EvaluationSummaryPage,
            summary="Evaluation bookkeeping per generation (counts and attempts)",
            responses=error_responses(404))
def job_evaluations(
    job_id: str,
    repo: RepoDep,
    after: Annotated[int, Query(
        ge=-1, le=MAX_OFFSET,
        description="only generations after this one (-1: all); the final re-evaluation "
                    "(generation -1) is always included once it exists")] = -1,
) -> dict[str, Any]:
    """Per generation: population, done / pending / failed, attempts and repeated attempts
    (one query). Poll with `after` = the newest generation that had nothing pending."""
    job = repo.get_job(job_id)
    return {"job_id": job_id, "status": job.status, "after": after,
            "generations": repo.evaluation_summary(job_id, after=after)}


@router.get("/{job_id}/best", response_model=schemas.JobBest,
            summary="The best candidate so far as a CMRT curve",
            responses=error_responses(404))
def job_best(job_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    """The job's best candidate so far (or finished with), decoded on the job's spec: knot
    times, values and the sampled curve (`null` until a generation has been recorded)."""
    job = repo.get_job(job_id)
    out: dict[str, Any] = {"job_id": job_id, "status": job.status,
                           "iterations": job.iterations,
                           "best_objective": job.best_objective, "params": job.best_params,
                           "knot_times": None, "values": None, "vertical_values": None,
                           "curve": None,
                           "cmrt_id": job_cmrt_id(repo, job)}
    if job.best_params is not None:
        spline = decode(jobs.stored_job_spec(job).spec, job.best_params)
        out["knot_times"] = [float(v) for v in spline.knot_times]
        out["values"] = [float(v) for v in spline.values]
        if spline.vertical_values is not None:
            out["vertical_values"] = [float(v) for v in spline.vertical_values]
        out["curve"] = sample_curve(spline)
    return out


@router.post("/{job_id}/cancel", status_code=202, summary="Cancel a job",
             response_model=schemas.CancelAccepted,
             responses=error_responses(404, 409))
def cancel_job(job_id: str, request: Request, repo: RepoDep) -> JSONResponse:
    job = repo.get_job(job_id)
    if job.terminal:
        raise HttpError(409, f"job {job_id} already finished ({job.status})")
    job = repo.request_cancel(job_id)
    return JSONResponse({"id": job.id, "status": job.status,
                         "cancel_requested": job.cancel_requested,
                         "url": url_for(request, "get_job", job_id=job.id)},
                        status_code=202)
