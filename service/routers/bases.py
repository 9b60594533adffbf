"""`/bases`: PCA bases of a family's library CMRTs (reduced-space search)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse

from application.bases import build_library_basis
from service import schemas
from service.body import read_model
from service.deps import MAX_OFFSET, RepoDep, SettingsDep
from service.openapi import error_responses, json_body
from service.views import basis_out

router = APIRouter(prefix="/bases", tags=["library"])


@router.post("", status_code=201, summary="Build a PCA basis", response_model=schemas.BasisOut,
             openapi_extra=json_body(schemas.BasisRequest, example=schemas.BASIS_EXAMPLE),
             responses={**error_responses(400, 413, 415, 422),
                        404: {"model": schemas.Problem,
                              "description": "The family has no library CMRTs"}})
async def create_basis(request: Request, repo: RepoDep, settings: SettingsDep) -> JSONResponse:
    """Body `{"family": "bend", "k": 3}`: PCA of the family's library CMRTs."""
    req = await read_model(request, schemas.BasisRequest, settings.max_body_bytes)
    basis_id = build_library_basis(repo, req.family, req.k)
    body = schemas.BasisOut.model_validate(basis_out(repo.get_basis(basis_id), request))
    return JSONResponse(body.model_dump(mode="json"), status_code=201,  # ISO 8601 times
                        headers={"Location": body.url})


@router.get("", response_model=schemas.BasisPage, summary="List PCA bases",
            responses=error_responses(422))
def list_bases(
    request: Request,
    repo: RepoDep,
    family: Annotated[str | None, Query(max_length=100)] = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> dict[str, Any]:
    """Newest first: each basis' variance explained per component and its members (library
    CMRT ids)."""
    items, total = repo.list_bases(family, limit=limit, offset=offset)
    return {"items": [basis_out(b, request) for b in items], "total": total,
            "limit": limit, "offset": offset}


@router.get("/{basis_id}", summary="One PCA basis", response_model=schemas.BasisOut,
            responses=error_responses(404))
def get_basis(basis_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    return basis_out(repo.get_basis(basis_id), request)
