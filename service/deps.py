"""FastAPI dependencies of the routers: the process's settings, repository, executor and job
runner (built once by `service.app.create_app` and kept on `app.state.services`), and the
parsing helpers of query strings shared by several routes.

Every dependency here is `async def` although none awaits: FastAPI runs a plain `def`
dependency in its thread pool, a hand-off to a thread and back (about 0.1 ms on an idle machine,
more on a busy one) for what is a dictionary lookup or a scan of the query string."""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, Request

from application.simulations import SimulationPool
from cmrt.settings import Settings
from service.errors import HttpError
from store import Repository
from worker.executors import GenerationExecutor
from worker.runner import JobRunner


@dataclass
class Services:
    """What the routes of one app share."""

    settings: Settings
    repo: Repository
    executor: GenerationExecutor
    runner: JobRunner
    #: What-if clips (POST /simulations).
    simulations: SimulationPool
    #: False: jobs are stored but not driven (tests of the HTTP layer alone).
    run_drivers: bool = True


async def services(request: Request) -> Services:
    return request.app.state.services


async def get_settings_dep(s: Annotated[Services, Depends(services)]) -> Settings:
    return s.settings


async def get_repo(s: Annotated[Services, Depends(services)]) -> Repository:
    return s.repo


SettingsDep = Annotated[Settings, Depends(get_settings_dep)]
RepoDep = Annotated[Repository, Depends(get_repo)]
ServicesDep = Annotated[Services, Depends(services)]


def url_for(request: Request, name: str, **params: Any) -> str:
    """The URL of a route: a path (`/jobs/<id>`) unless `CMRT_PUBLIC_URL` sets the base.

    Never built from the request's Host header, which the client controls."""
    path = str(request.app.url_path_for(name, **params))
    base = request.app.state.services.settings.public_url
    return f"{base.rstrip('/')}{path}" if base else path


class RequestLinks:
    """`application.simulations.Links` of a request: the URLs of a library CMRT and a job as
    `url_for` builds them."""

    def __init__(self, request: Request) -> None:
        self._request = request

    def cmrt(self, cmrt_id: str) -> str:
        """The URL of library CMRT `cmrt_id` (GET /cmrts/{id})."""
        return url_for(self._request, "get_cmrt", cmrt_id=cmrt_id)

    def job(self, job_id: str) -> str:
        """The URL of job `job_id` (GET /jobs/{id})."""
        return url_for(self._request, "get_job", job_id=job_id)


#: Largest `offset` of a listing and `after` of a generation poll: far below what an SQL
#: integer holds (2^63 - 1), far above any real listing.
MAX_OFFSET = 10**9


async def no_nul(request: Request) -> None:
    """Refuse a NUL character in the path or the query (PostgreSQL cannot store or compare it;
    no id, family or parameter name contains one)."""
    if "\x00" in request.url.path:
        raise HttpError(422, "path: the NUL character is not allowed")
    for k, v in request.query_params.multi_items():
        if "\x00" in k or "\x00" in v:
            raise HttpError(422, f"{k.replace(chr(0), '')}: the NUL character is not allowed")


def refuse_query(*names: str) -> Callable[[Request], Awaitable[None]]:
    """A dependency refusing the query parameters `names` (fields that belong in the body: a
    request naming them in its query would see them silently ignored otherwise)."""
    async def refuse(request: Request) -> None:
        for name in names:
            if name in request.query_params:
                raise HttpError(422, f"{name}: query parameters are not accepted; send it in "
                                     "the body")
    return refuse


#: Query keys of /cmrts and /cmrts/interpolate that are not task parameters.
RESERVED_QUERY_KEYS = {"family", "tolerance", "limit", "offset", "extrapolate", "along", "curves",
                       "verify"}
#: Most task parameters accepted in one library query.
MAX_QUERY_PARAMS = 16
#: Longest name of a task parameter in a library query.
MAX_PARAM_NAME = 64


def finite_query(name: str, raw: str) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise HttpError(422, f"{name}: {raw!r} is not a number") from None
    if not math.isfinite(v):
        raise HttpError(422, f"{name}: must be a finite number, got {raw!r}")
    return v


async def library_query(request: Request) -> dict[str, float]:
    """The task parameters of a library query: every query key not in RESERVED_QUERY_KEYS."""
    params: dict[str, float] = {}
    for k, v in request.query_params.multi_items():
        if k in RESERVED_QUERY_KEYS:
            continue
        if len(k) > MAX_PARAM_NAME:
            raise HttpError(422, f"parameter name {k[:MAX_PARAM_NAME]!r}...: longer than "
                                f"{MAX_PARAM_NAME} characters")
        if k in params:
            raise HttpError(422, f"{k}: given more than once")
        params[k] = finite_query(k, v)
    if len(params) > MAX_QUERY_PARAMS:
        raise HttpError(422, f"at most {MAX_QUERY_PARAMS} task parameters per query")
    return params


LibraryParams = Annotated[dict[str, float], Depends(library_query)]


def task_parameters_doc(required: bool) -> dict[str, Any]:
    """`openapi_extra=` documenting the free-form task-parameter query keys that
    `library_query` reads (`?duration=0.4&force=250`)."""
    return {"parameters": [{
        "name": "task_parameters", "in": "query", "required": required,
        "style": "form", "explode": True,
        "description": "Any other query key is a task parameter with a finite number, e.g. "
                       "`duration=0.4`, `mass=60` (or its spec path, `task.mass=60`).",
        "schema": {"type": "object", "minProperties": 1 if required else 0,
                   "maxProperties": MAX_QUERY_PARAMS,
                   "propertyNames": {"minLength": 1, "maxLength": MAX_PARAM_NAME,
                                     "pattern": "^[A-Za-z_][A-Za-z0-9_.]*$",
                                     "not": {"enum": sorted(RESERVED_QUERY_KEYS)}},
                   "additionalProperties": {"type": "number"}},
    }]}
