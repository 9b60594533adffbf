"""`/jobs`: submit a task spec for optimisation, follow it, cancel it."""

from __future__ import annotations

from dataclasses import asdict, fields
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import JSONResponse

from application import jobs
from service import schemas
from service.body import read_json
from service.deps import MAX_OFFSET, RepoDep, ServicesDep, refuse_query, url_for
from service.openapi import error_responses, json_body
from service.views import generation_out, job_cmrt_id, job_out
from store.records import JOB_STATUSES

router = APIRouter(prefix="/jobs", tags=["jobs"])

JobStatus = Literal[JOB_STATUSES]  # type: ignore[valid-type]


@router.post("", status_code=202, response_model=schemas.JobAccepted,
             summary="Submit a task spec for optimisation",
             openapi_extra=json_body(
                 schemas.JobRequest, example={"spec": schemas.JOB_EXAMPLE, "seed": 1},
                 description="the job request `{spec, seed, basis, start}`: the task spec "
                             "as `spec`"),
             dependencies=[Depends(refuse_query(*jobs.REQUEST_FIELDS[1:]))],
             responses=error_responses(400, 413, 415, 422))
async def submit_job(request: Request, svc: ServicesDep) -> JSONResponse:
    """Body: `{"spec": {...}, "seed": n, "basis": "<basis id>", "start": "library"}`, the
    spec as the CLI's YAML/JSON files, under `spec`. 202 with the job's URL in `Location`."""
    data = await read_json(request, svc.settings.max_body_bytes)
    accepted = jobs.submit_request(svc.repo, svc.settings, data)
    if svc.run_drivers:
        svc.runner.submit(accepted.job.id)
    url = url_for(request, "get_job", job_id=accepted.job.id)
    return JSONResponse({"id": accepted.job.id, "url": url, "status": accepted.job.status,
                         "budget": accepted.budget.to_dict()},
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
    best = jobs.best_curve(job)
    return {"job_id": job_id, "status": job.status, "iterations": job.iterations,
            "best_objective": job.best_objective, "params": job.best_params,
            **(asdict(best) if best is not None else dict.fromkeys(
                f.name for f in fields(jobs.BestCurve))),
            "cmrt_id": job_cmrt_id(repo, job)}


@router.post("/{job_id}/cancel", status_code=202, summary="Cancel a job",
             response_model=schemas.CancelAccepted,
             responses=error_responses(404, 409))
def cancel_job(job_id: str, request: Request, repo: RepoDep) -> JSONResponse:
    job = jobs.cancel_job(repo, job_id)
    return JSONResponse({"id": job.id, "status": job.status,
                         "cancel_requested": job.cancel_requested,
                         "url": url_for(request, "get_job", job_id=job.id)},
                        status_code=202)
