"""`/cmrts`: the library of learned CMRTs, queried by task parameters, and interpolation."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request

from application import answers
from optim.errors import InterpolationError
from service import schemas
from service.deps import (
    MAX_OFFSET,
    LibraryParams,
    RepoDep,
    ServicesDep,
    task_parameters_doc,
    url_for,
)
from service.errors import HttpError
from service.openapi import error_responses
from service.routers.simulations import RETRY_AFTER_S
from service.simulations import SimulationBusyError
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
        raise HttpError(422, "family: required when querying by task parameters")
    if not params:
        items, total = repo.list_cmrts(family, limit=limit, offset=offset)
    else:
        find = repo.find_cmrts if curves else repo.find_cmrt_keys  # keys: no JSON read
        try:
            found = find(family, params, tolerance=tolerance)
        except ValueError as err:
            raise HttpError(422, str(err)) from None
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


def query_point(repo: Any, family: str, params: dict[str, float], along: str | None,
                 where: str = "") -> tuple[str, float, dict[str, float], str | None]:
    """(library key, value, the other parameters, a note on a translated name) of a query at
    task parameters `params` (`along` names the interpolated one when there are several)."""
    if not params:
        raise HttpError(422, f"{where}a task parameter to interpolate at is required, e.g. "
                            "mass=60")
    if along is None:
        if len(params) > 1:
            raise HttpError(422, "along: required when several task parameters are given")
        along = next(iter(params))
    if along not in params:
        raise HttpError(422, f"along: {along!r} is not among the given parameters")
    notes, named = [], {}
    for name, v in params.items():
        key = name
        if "." in name:  # a spec path (task.mass): the library names it by its key
            try:
                key, note = answers.library_parameter(repo, family, name)
            except answers.AnswerError as err:
                raise HttpError(422, f"{where}{err}") from None
            if note:
                notes.append(note)
        if key in named:
            raise HttpError(422, f"{where}{name}: given twice ({key})")
        named[key] = v
        if name == along:
            along = key
    value = named.pop(along)
    return along, value, named, "; ".join(notes) or None


def _refine_offer(request: Request, out: dict[str, Any]) -> dict[str, Any] | None:
    """How to ask for a refinement where the answer is not a good one."""
    if out["verdict"] == "good" or out["exact"]:  # a member optimised there: nothing to refine
        return None
    params = {out["key"]: out["value"]}
    return {"method": "POST", "url": url_for(request, "refine_cmrt"),
            "body": {"family": out["family"], "parameters": params},
            "command": f"cmrt library refine --family {out['family']} "
                       f"{out['key']}={out['value']:g} --wait"}


@router.get("/interpolate", summary="The library's answer at a task parameter",
            response_model=schemas.LibraryAnswer, responses=error_responses(422, 503),
            openapi_extra=task_parameters_doc(True))
def interpolate_cmrt(
    request: Request,
    svc: ServicesDep,
    params: LibraryParams,
    family: Annotated[str, Query(max_length=100)],
    extrapolate: bool = False,
    along: Annotated[str | None, Query(max_length=64)] = None,
    verify: Annotated[bool, Query(
        description="simulate the answer once at the query's value (kept in the library: the "
                    "next identical query costs nothing); an answer that falls, fails its "
                    "task or is weak is replaced by the best neighbouring member that stands, "
                    "or said plainly to be no good")] = False,
) -> dict[str, Any]:
    """`GET /cmrts/interpolate?family=bend&duration=0.5[&verify=true]`: the CMRT the library
    serves there and what it is: `source` (member, interpolated, refined), the `members` it
    was built from, the neighbours' `switch` check (no average across a strategy switch: the
    nearer member is served), and with `verify` its simulated `outcome` and `verdict`.
    Outside the stored range only with `extrapolate=true`. With several parameters, `along`
    names the interpolated one and the others must match exactly."""
    key, value, filters, note = query_point(svc.repo, family, params, along)
    simulate = svc.simulations.simulate if verify else None
    try:
        out = answers.serve(svc.repo, family, key, value, filters=filters,
                            extrapolate=extrapolate, simulate=simulate)
    except (InterpolationError, answers.AnswerError) as err:
        raise HttpError(422, str(err)) from None
    except SimulationBusyError:
        raise HttpError(503, "verify: every simulation process is busy; retry later",
                       headers={"Retry-After": str(RETRY_AFTER_S)}) from None
    out["note"] = note
    for n in out["neighbours"]:
        n["url"] = url_for(request, "get_cmrt", cmrt_id=n["id"])
    out["refine"] = _refine_offer(request, out)
    return out


@router.get("/{cmrt_id}", summary="One CMRT with its curve", response_model=schemas.CmrtOut,
            responses=error_responses(404))
def get_cmrt(cmrt_id: str, request: Request, repo: RepoDep) -> dict[str, Any]:
    return cmrt_out(repo.get_cmrt(cmrt_id), request, full=True)
