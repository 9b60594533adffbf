"""`/refinements`: a refinement of the library's answer at a task parameter, a job searching
the family's PCA basis from the best answer the library has there; its result joins the
library as a member of the family."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from application import answers
from service import schemas
from service.body import read_model
from service.deps import ServicesDep, url_for
from service.openapi import error_responses, json_body
from service.views import answer_out

router = APIRouter(prefix="/refinements", tags=["library"])


@router.post("", status_code=202, response_model=schemas.RefineAccepted,
             summary="Refine the library's answer in the family's PCA basis",
             openapi_extra=json_body(schemas.RefineRequest, example=schemas.REFINE_EXAMPLE),
             responses=error_responses(400, 413, 415, 422))
async def refine_cmrt(request: Request, svc: ServicesDep) -> JSONResponse:
    """Body `{"family": "domino", "parameters": {"mass": 45}, "basis"?: id,
    "max_evaluations"?: 150, "seed"?: 0}`: a job searching the family's newest PCA basis (or
    `basis`), started at the best answer the library has there, under a small budget; its
    result joins the library as a member (`source: refined`). 202 with the job."""
    req = await read_model(request, schemas.RefineRequest, svc.settings.max_body_bytes)
    query = answers.LibraryQuery(req.family, req.parameters, req.along, req.extrapolate,
                                 where="parameters: ")
    got = answers.refine(svc.repo, svc.settings, answers.Refine(
        query, basis_id=req.basis, max_evaluations=req.max_evaluations, seed=req.seed))
    job = got.job
    if svc.run_drivers:
        svc.runner.submit(job.id)
    url = url_for(request, "get_job", job_id=job.id)
    body = schemas.RefineAccepted(
        id=job.id, url=url, status=job.status, budget=got.budget.to_dict(),
        basis_id=job.basis_id, start=job.start.to_json() if job.start else None,
        answer=answer_out(got.answer, request, offer=False))
    return JSONResponse(body.model_dump(mode="json"), status_code=202, headers={"Location": url})
