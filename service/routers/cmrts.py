"""`/cmrts`: the library of learned CMRTs, queried by task parameters, and interpolation."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request

from application import answers, library
from service import schemas
from service.deps import (
    MAX_OFFSET,
    LibraryParams,
    RepoDep,
    ServicesDep,
    task_parameters_doc,
)
from service.openapi import error_responses
from service.views import answer_out, cmrt_out

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
    items, total = library.find_cmrts(repo, family, params, tolerance=tolerance, limit=limit,
                                      offset=offset, curves=curves)
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


@router.get("/interpolate", summary="The library's answer at a task parameter",
            response_model=schemas.LibraryAnswer, responses=error_responses(422, 503),
            openapi_extra=task_parameters_doc(True))
def interpolate_cmrt(
    request: Request,
    svc: ServicesDep,
    params: LibraryParams,
    family: Annotated[str, Query(min_length=1, max_length=100)],
    extrapolate: bool = False,
    along: Annotated[str | None, Query(
        min_length=1, max_length=64,
        description="the interpolated parameter, one of those given; required with several"
    )] = None,
    verify: Annotated[bool, Query(
        description="simulate the answer once at the query's value (kept in the library: the "
                    "next identical query costs nothing); an answer that falls, fails its "
                    "task or is weak is replaced by the best neighbouring member that stands, "
                    "or said plainly to be no good")] = False,
) -> schemas.LibraryAnswer:
    """`GET /cmrts/interpolate?family=bend&duration=0.5[&verify=true]`: the CMRT the library
    serves there and what it is: `source` (member, interpolated, refined), the `members` it
    was built from, the neighbours' `switch` check (no average across a strategy switch: the
    nearer member is served), and with `verify` its simulated `outcome` and `verdict`.
    Outside the stored range only with `extrapolate=true`. With several parameters, `along`
    names the interpolated one and the others must match exactly."""
    query = answers.LibraryQuery(family, params, along, extrapolate)
    # every simulation process busy: application.simulations.SimulationBusyError, a 503
    simulate = svc.simulations.simulate if verify else None
    return answer_out(answers.serve(svc.repo, query, simulate), request)


@router.get("/{cmrt_id}", summary="One CMRT with its curve", response_model=schemas.CmrtOut,
            responses=error_responses(404))
def get_cmrt(cmrt_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    return cmrt_out(repo.get_cmrt(cmrt_id), request, full=True)
