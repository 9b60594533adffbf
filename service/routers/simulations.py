"""`/simulations`: what-if runs of one clip (a spec with a library CMRT, a job's best
candidate, inline parameters, or none), answered synchronously (`application.simulations`)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from application import simulations
from application.characters import request_with_stored_character
from service import schemas
from service.body import read_model
from service.deps import RequestLinks, ServicesDep
from service.openapi import error_responses, json_body

router = APIRouter(prefix="/simulations", tags=["simulations"])


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
                           prepare=lambda data: request_with_stored_character(svc.repo, data))
    out = await simulations.simulate(svc.repo, svc.simulations, RequestLinks(request), req)
    return JSONResponse(schemas.SimulationOut.model_validate(out).model_dump(mode="json"))
