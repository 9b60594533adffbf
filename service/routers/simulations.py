"""`/simulations`: what-if runs of one clip (a spec with a library CMRT, a job's best
candidate, inline parameters, or none), answered synchronously."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from application.characters import with_stored_character
from application.simulations import SimulationBusyError
from optim.errors import ParamsError
from optim.spline import check_params
from service import schemas
from service.body import read_model
from service.deps import ServicesDep, url_for
from service.errors import HttpError
from service.openapi import error_responses, json_body
from store import NotFound

router = APIRouter(prefix="/simulations", tags=["simulations"])
log = logging.getLogger("cmrt.service.simulations")

#: Seconds a client is told to wait when every simulation process is busy.
RETRY_AFTER_S = 5


def _params(svc: Any, request: Request, req: schemas.SimulationRequest
            ) -> tuple[list[float] | None, dict[str, Any] | None]:
    """The CMRT's parameter vector for the request's spec, and how it was chosen."""
    c = req.cmrt
    if c is None:
        return None, None
    if isinstance(c, schemas.LibraryCmrtRef):
        try:
            rec = svc.repo.get_cmrt(c.id)
        except NotFound:
            raise HttpError(422, f"cmrt.id: no library CMRT {c.id!r}") from None
        params, about = rec.params, {"source": "library", "id": rec.id,
                                     "url": url_for(request, "get_cmrt", cmrt_id=rec.id)}
    elif isinstance(c, schemas.JobBestCmrt):
        try:
            job = svc.repo.get_job(c.id)
        except NotFound:
            raise HttpError(422, f"cmrt.id: no job {c.id!r}") from None
        if job.best_params is None:
            raise HttpError(422, f"cmrt.id: job {c.id!r} has no best candidate yet "
                                f"({job.status})")
        params, about = job.best_params, {"source": "job", "id": job.id,
                                          "url": url_for(request, "get_job", job_id=job.id),
                                          "job_objective": job.best_objective}
    else:
        params, about = c.params, {"source": "params"}
    try:
        checked = check_params(req.spec, params)
    except ParamsError as err:
        raise HttpError(422, f"cmrt.{err}") from None
    about["params"] = [float(v) for v in checked]
    return about["params"], about


def _stored_character(svc: Any, data: Any) -> Any:
    """The request with the definition of a stored character its spec names put in."""
    if isinstance(data, dict) and "spec" in data:
        return {**data, "spec": with_stored_character(svc.repo, data["spec"])}
    return data


@router.post("", response_model=schemas.SimulationOut, summary="Simulate one clip (what-if)",
             openapi_extra=json_body(schemas.SimulationRequest,
                                     example=schemas.SIMULATION_EXAMPLE),
             responses=error_responses(400, 413, 415, 422, 503))
async def simulate(request: Request, svc: ServicesDep) -> JSONResponse:
    """Body `{"spec": {...}, "cmrt": {"source": "library", "id": ...} | {"source": "job",
    "id": ...} | {"source": "params", "params": [...]} | null, "traces": true,
    "frames": false}`. Runs the clip in the API's simulation pool and answers with the
    objective, whether and which way the character fell, the task's success and the traces;
    `status: "failed"` (with `error`) when the simulation diverges or its process dies."""
    req = await read_model(request, schemas.SimulationRequest, svc.settings.max_body_bytes,
                           prepare=lambda data: _stored_character(svc, data))
    params, about = _params(svc, request, req)
    try:
        out = await svc.simulations.run(req.spec.model_dump(mode="json"), params,
                                        traces=req.traces, frames=req.frames)
    except SimulationBusyError:
        raise HttpError(503, "simulations: every simulation process is busy; retry later",
                       headers={"Retry-After": str(RETRY_AFTER_S)}) from None
    out["cmrt"] = about
    log.info("simulation %s (%s, CMRT %s): %s in %.2f s CPU", req.spec.name, req.spec.task_type,
             about["source"] if about else "none", out["status"], out.get("cpu_seconds") or 0.0)
    return JSONResponse(schemas.SimulationOut.model_validate(out).model_dump(mode="json"))
