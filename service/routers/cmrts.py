"""`/cmrts`: the library of learned CMRTs, queried by task parameters, and interpolation."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request

from application.library import interpolate_library
from optim.errors import InterpolationError
from service import schemas
from service.deps import MAX_OFFSET, LibraryParams, RepoDep, task_parameters_doc, url_for
from service.errors import ApiError
from service.openapi import error_responses
from service.views import cmrt_out

router = APIRouter(prefix="/cmrts", tags=["library"])


@router.get("", summary="Find CMRTs by task parameters", response_model=schemas.CmrtPage,
            responses=error_responses(422), openapi_extra=task_parameters_doc(False))
def find_cmrts(
    request: Request,
    repo: RepoDep,
    params: LibraryParams,
    family: Annotated[str | None, Query(max_length=100)] = None,
    tolerance: Annotated[float | None, Query(
        ge=0, allow_inf_nan=False,
        description="nearest within +-tolerance; without it: exact match")] = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
    curves: Annotated[bool, Query(description="include each CMRT's sampled curve")] = False,
) -> dict[str, Any]:
    """`GET /cmrts?family=bend&duration=0.4[&tolerance=0.05]`: any other query key is a
    task parameter (e.g. duration, force). Nearest first when a tolerance is given. With
    `curves=true` every item carries its `curve` (one request draws a family)."""
    if params and family is None:
        raise ApiError(422, "family: required when querying by task parameters")
    if not params:
        items, total = repo.list_cmrts(family, limit=limit, offset=offset)
    else:
        try:
            found = repo.find_cmrts(family, params, tolerance=tolerance)
        except ValueError as err:
            raise ApiError(422, str(err)) from None
        total, items = len(found), found[offset:offset + limit]
    out = []
    for r in items:
        d = cmrt_out(r, request)
        if curves:
            d["curve"] = r.curve
        out.append(d)
    return {"items": out, "total": total,
            "limit": limit, "offset": offset}


@router.get("/families", summary="The library's families and their sizes",
            response_model=schemas.LibraryFamilies)
def library_families(repo: RepoDep) -> dict[str, Any]:
    """`GET /cmrts/families`: every family name in the library with its number of CMRTs, by
    name (one grouped query; what a client lists before asking for one family's CMRTs)."""
    items = [{"family": f, "count": n} for f, n in repo.cmrt_families()]
    return {"items": items, "total": len(items)}


@router.get("/interpolate", summary="Interpolate a CMRT",
            responses=error_responses(422), openapi_extra=task_parameters_doc(True))
def interpolate_cmrt(
    request: Request,
    repo: RepoDep,
    params: LibraryParams,
    family: Annotated[str, Query(max_length=100)],
    extrapolate: bool = False,
    along: Annotated[str | None, Query(max_length=64)] = None,
) -> dict[str, Any]:
    """`GET /cmrts/interpolate?family=bend&duration=0.5`: linear interpolation between the
    two library CMRTs nearest on either side; outside the stored range only with
    `extrapolate=true`. With several parameters, `along` names the interpolated one and
    the others must match exactly."""
    if not params:
        raise ApiError(422, "a task parameter to interpolate at is required, e.g. duration=0.5")
    if along is None:
        if len(params) > 1:
            raise ApiError(422, "along: required when several task parameters are given")
        along = next(iter(params))
    if along not in params:
        raise ApiError(422, f"along: {along!r} is not among the given parameters")
    filters = dict(params)
    value = filters.pop(along)
    try:
        out = interpolate_library(repo, family, along, value, filters=filters,
                                  extrapolate=extrapolate)
    except InterpolationError as err:
        raise ApiError(422, str(err)) from None
    for n in out["neighbours"]:
        n["url"] = url_for(request, "get_cmrt", cmrt_id=n["id"])
    return out


@router.get("/{cmrt_id}", summary="One CMRT with its curve", response_model=schemas.CmrtOut,
            responses=error_responses(404))
def get_cmrt(cmrt_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    return cmrt_out(repo.get_cmrt(cmrt_id), request, full=True)
