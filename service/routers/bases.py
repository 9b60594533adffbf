"""`/bases`: PCA bases of a family's library CMRTs (reduced-space search)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from pydantic import ValidationError

from optim.errors import BasisError
from service import schemas
from service.body import read_json
from service.deps import RepoDep, SettingsDep
from service.errors import ApiError, validation_message
from service.openapi import error_responses, json_body
from service.views import basis_out
from worker.library import build_library_basis

router = APIRouter(prefix="/bases", tags=["library"])


@router.post("", status_code=201, summary="Build a PCA basis",
             openapi_extra=json_body(schemas.BasisRequest, example=schemas.BASIS_EXAMPLE),
             responses=error_responses(400, 413, 415, 422))
async def create_basis(request: Request, repo: RepoDep, settings: SettingsDep) -> JSONResponse:
    """Body `{"family": "bend", "k": 3}`: PCA of the family's library CMRTs."""
    data = await read_json(request, settings.max_body_bytes)
    try:
        req = schemas.BasisRequest.model_validate(data)
    except ValidationError as err:
        raise ApiError(422, validation_message(err.errors())) from None
    try:
        basis_id = build_library_basis(repo, req.family, req.k)
    except BasisError as err:
        raise ApiError(422, str(err)) from None
    body = basis_out(repo.get_basis(basis_id), request)
    return JSONResponse(json.loads(json.dumps(body, default=str)), status_code=201,
                        headers={"Location": body["url"]})


@router.get("/{basis_id}", summary="One PCA basis", responses=error_responses(404))
def get_basis(basis_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    return basis_out(repo.get_basis(basis_id), request)
