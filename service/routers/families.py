"""`/families`: grow the library along one task parameter in one request (optim.family): the
members, warm-started from each other, then the PCA basis and its checks (Table 2)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse

from application import families as app_families
from service import paper, schemas
from service.body import read_json
from service.deps import MAX_OFFSET, RepoDep, ServicesDep, url_for
from service.openapi import error_responses, json_body
from store import FamilyRecord, Repository
from store.records import FAMILY_STATUSES

router = APIRouter(prefix="/families", tags=["families"])


def family_out(fam: FamilyRecord, request: Request, repo: Repository, *, full: bool = False,
               curves: bool = False) -> schemas.FamilyOut:
    """A family as the API serves it; `full`: its request, runs, progress and once done its
    report (application.families.family_detail) and the paper's Table 2 where the task has
    one (fields not given are left out of the answer)."""
    head: dict[str, Any] = {
        "id": fam.id,
        "url": url_for(request, "get_family", family_id=fam.id),
        "family": fam.family,
        "param": fam.param,
        "status": fam.status,
        "error": fam.error,
        "cancel_requested": fam.cancel_requested,
        "created_at": fam.created_at,
        "finished_at": fam.finished_at,
        "values": fam.spec.get("values"),
        "strategy": fam.spec.get("strategy"),
        "links": {"cancel": url_for(request, "cancel_family", family_id=fam.id),
                  "dashboard": url_for(request, "dashboard_family", family_id=fam.id)},
    }
    if not full:
        return schemas.FamilyOut(**head)
    d = app_families.family_detail(
        repo, fam, curves=curves, job_url=lambda job_id: url_for(request, "get_job",
                                                                 job_id=job_id))
    fs = app_families.family_spec(fam)  # parsed once per process
    return schemas.FamilyOut(**head, spec=d.spec, runs=d.runs, progress=d.progress,
                             members=d.members, basis=d.basis, checks=d.checks,
                             paper_table2=paper.table2(fs.base.task_type, fs.param))


@router.post("", status_code=202, summary="Grow a family of CMRTs along a task parameter",
             response_model=schemas.FamilyAccepted,
             openapi_extra=json_body(schemas.FamilySpec, example=schemas.FAMILY_EXAMPLE),
             responses=error_responses(400, 413, 415, 422))
async def submit_family(request: Request, svc: ServicesDep) -> JSONResponse:
    """Body: a family request (docs/families.md): the base task `spec`, the `param` path of
    one number in it, its `values`, the `strategy` (`independent` | `continuation` `from`
    low | high | both | middle, `warm` rules), `leave_out` values, `k`, `seed`. Every run is
    an ordinary job (listed under /jobs); the whole family is admitted against the job
    budget ceiling. 202 with the family's URL in `Location`."""
    data = await read_json(request, svc.settings.max_body_bytes)
    # validated (a stored character named: its definition), admitted as a whole, stored
    accepted = app_families.submit_family_request(svc.repo, svc.settings, data)
    url = url_for(request, "get_family", family_id=accepted.family.id)
    return JSONResponse({"id": accepted.family.id, "url": url, "status": accepted.family.status,
                         "runs": accepted.runs, "budget": accepted.budget.to_dict()},
                        status_code=202, headers={"Location": url})


@router.get("", summary="List families", response_model=schemas.FamilyPage,
            response_model_exclude_unset=True,
            responses=error_responses(422))
def list_families(
    request: Request,
    repo: RepoDep,
    status: Annotated[str | None, Query(pattern="^(" + "|".join(FAMILY_STATUSES) + ")$")] = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> dict[str, Any]:
    items, total = repo.list_families(status=status, limit=limit, offset=offset)
    return {"items": [family_out(f, request, repo) for f in items], "total": total,
            "limit": limit, "offset": offset}


@router.get("/{family_id}", summary="One family: runs, progress, members, basis, checks",
            response_model=schemas.FamilyOut, response_model_exclude_unset=True,
            responses=error_responses(404))
def get_family(
    family_id: str,
    request: Request,
    repo: RepoDep,
    curves: Annotated[bool, Query(description="each run's [evaluations, best so far]")] = False,
) -> schemas.FamilyOut:
    """Status and progress; every run of the plan with its job; once done, the members
    (objective, fell, task success, CMRT), the PCA basis and the checks (members'
    reconstruction errors and strategy switches, interpolation probes, Table 2 rows), and the
    paper's Table 2 where the task has one."""
    return family_out(repo.get_family(family_id), request, repo, full=True, curves=curves)


@router.post("/{family_id}/cancel", status_code=202, summary="Cancel a family",
             response_model=schemas.CancelAccepted,
             responses=error_responses(404))
def cancel_family(family_id: str, request: Request, repo: RepoDep) -> JSONResponse:
    """Its unfinished runs are cancelled; the family ends `cancelled` (a finished family is
    left as it is)."""
    fam = repo.request_family_cancel(family_id)
    return JSONResponse({"id": fam.id, "status": fam.status,
                         "cancel_requested": fam.cancel_requested,
                         "url": url_for(request, "get_family", family_id=fam.id)},
                        status_code=202)
