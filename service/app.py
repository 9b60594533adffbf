"""The FastAPI app factory: `create_app()`.

The API process also hosts the job drivers (worker.runner.JobRunner, background threads): a job
is driven by whichever API process holds its lease, evaluations run in the local process pool
(embedded default: no broker configured) or on Celery workers (CMRT_BROKER_URL set). On start-up
the runner resumes queued/running jobs whose driver lease expired.

Errors: 400 malformed JSON, 404 unknown id, 409 conflicting state, 413 body too large, 422 a
field breaking a rule (the message names the field and the rule); nothing is stored on a 4xx.
"""

from __future__ import annotations

import json
import logging
import math
from contextlib import asynccontextmanager
from importlib import resources
from typing import Annotated, Any

from fastapi import FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse

from cmrt.settings import Settings, get_settings
from optim.errors import BasisError, InterpolationError
from service import schemas
from sim.errors import SpecError
from sim.spec import parse_spec
from store import NotFound, Repository, open_repository
from store.records import JOB_STATUSES
from worker import admission
from worker.executors import CeleryExecutor, GenerationExecutor, make_generation_executor
from worker.library import build_library_basis, interpolate_library
from worker.runner import JobRunner

log = logging.getLogger("cmrt.service")

#: Query keys of /cmrts and /cmrts/interpolate that are not task parameters.
_RESERVED = {"family", "tolerance", "limit", "offset", "extrapolate", "along"}
#: Most task parameters accepted in one library query.
MAX_QUERY_PARAMS = 16


class ApiError(Exception):
    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


def _finite(name: str, raw: str) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise ApiError(422, f"{name}: {raw!r} is not a number") from None
    if not math.isfinite(v):
        raise ApiError(422, f"{name}: must be a finite number, got {raw!r}")
    return v


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


async def _read_json(request: Request, limit: int) -> Any:
    """The request body as JSON, refusing bodies over `limit` bytes (413) and bad JSON (400)."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise ApiError(413, f"request body of {declared} bytes exceeds the limit of {limit} bytes")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise ApiError(413, f"request body exceeds the limit of {limit} bytes")
    if not body.strip():
        raise ApiError(400, "malformed JSON: the request body is empty")
    try:
        return json.loads(bytes(body), parse_constant=_reject_constant)
    except (ValueError, UnicodeDecodeError) as err:
        raise ApiError(400, f"malformed JSON: {err}") from None


def _job_out(job: Any, request: Request, cmrt_id: str | None = None) -> dict[str, Any]:
    base = str(request.url_for("get_job", job_id=job.id))
    d = {
        "id": job.id,
        "url": base,
        "name": job.name,
        "family": job.family,
        "task": job.task,
        "status": job.status,
        "stop_rule": job.stop_rule,
        "error": job.error,
        "seed": job.seed,
        "basis_id": job.basis_id,
        "created_at": job.created_at,
        "started_at": job.started_at,
        "finished_at": job.finished_at,
        "best_objective": job.best_objective,
        "best_params": job.best_params,
        "evaluations": job.evaluations,
        "iterations": job.iterations,
        "cancel_requested": job.cancel_requested,
        "cmrt_id": cmrt_id,
        "links": {
            "generations": str(request.url_for("job_generations", job_id=job.id)),
            "evaluations": str(request.url_for("job_evaluations", job_id=job.id)),
            "cancel": str(request.url_for("cancel_job", job_id=job.id)),
            "dashboard": str(request.url_for("dashboard")) + f"?job={job.id}",
        },
    }
    return d


def _gen_out(g: Any) -> dict[str, Any]:
    return {
        "iteration": g.iteration,
        "best": g.best,
        "median": g.median,
        "worst": g.worst,
        "sigma": g.sigma,
        "best_so_far": g.best_so_far,
        "evaluations": g.evaluations,
        "wall_time": g.wall_time,
        "created_at": g.created_at,
    }


def _cmrt_out(r: Any, request: Request, full: bool = False) -> dict[str, Any]:
    d = {
        "id": r.id,
        "url": str(request.url_for("get_cmrt", cmrt_id=r.id)),
        "family": r.family,
        "task_parameters": r.task_parameters,
        "character": r.character,
        "objective": r.objective,
        "objective_without": r.objective_without,
        "winner": r.winner,
        "fell": r.fell,
        "job_id": r.job_id,
        "created_at": r.created_at,
    }
    if full:
        d.update(
            clip={"preparation": r.preparation, "duration": r.duration, "decay": r.decay,
                  "length": r.preparation + r.duration + r.decay},
            params=r.params,
            knot_times=r.knots,
            values=r.values,
            curve=r.curve,
            fell_without=r.fell_without,
            source={"job_id": r.job_id, "spec": r.spec,
                    "job_url": None if r.job_id is None
                    else str(request.url_for("get_job", job_id=r.job_id))},
        )
    return d


def _library_query(request: Request) -> dict[str, float]:
    params = {}
    for k, v in request.query_params.multi_items():
        if k in _RESERVED:
            continue
        if len(k) > 64:
            raise ApiError(422, f"parameter name {k[:64]!r}...: longer than 64 characters")
        if k in params:
            raise ApiError(422, f"{k}: given more than once")
        params[k] = _finite(k, v)
    if len(params) > MAX_QUERY_PARAMS:
        raise ApiError(422, f"at most {MAX_QUERY_PARAMS} task parameters per query")
    return params


def create_app(
    settings: Settings | None = None,
    *,
    repo: Repository | None = None,
    executor: GenerationExecutor | None = None,
    run_drivers: bool = True,
) -> FastAPI:
    """Build the app. Defaults: settings from the environment (`cmrt.settings.get_settings`),
    repository migrated to the newest schema, executor chosen by the broker setting."""
    config = settings or get_settings()
    repo = repo or open_repository(config.database_url)
    executor = executor or make_generation_executor(config)
    runner = JobRunner(repo, executor, config)
    max_body = config.max_body_bytes

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if run_drivers:
            runner.start()
        yield
        runner.stop(timeout=5)
        executor.close()

    app = FastAPI(
        title="CMRT service",
        version="0.1.0",
        description="Learns centre-of-mass reference trajectories (CMRTs) by CMA-ES over "
                    "physics simulations, and serves them from a library. See docs/service.md.",
        lifespan=lifespan,
    )
    app.state.repo = repo
    app.state.runner = runner
    app.state.executor = executor
    app.state.config = config

    @app.exception_handler(ApiError)
    async def _api_error(_: Request, err: ApiError) -> JSONResponse:
        return JSONResponse({"detail": err.detail}, status_code=err.status)

    @app.exception_handler(NotFound)
    async def _not_found(_: Request, err: NotFound) -> JSONResponse:
        return JSONResponse({"detail": str(err)}, status_code=404)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, err: RequestValidationError) -> JSONResponse:
        parts = []
        for e in err.errors():
            loc = ".".join(str(p) for p in e["loc"] if p not in ("query", "path", "body"))
            parts.append(f"{loc or 'request'}: {e['msg']}")
        return JSONResponse({"detail": "; ".join(parts)}, status_code=422)

    # ---- jobs ---------------------------------------------------------------------------
    @app.post("/jobs", status_code=202, response_model=schemas.JobAccepted, tags=["jobs"],
              summary="Submit a task spec for optimisation",
              openapi_extra={"requestBody": {"required": True, "content": {"application/json": {
                  "schema": schemas.JobRequest.model_json_schema()}}}},
              responses={400: {"model": schemas.Problem}, 413: {"model": schemas.Problem},
                         422: {"model": schemas.Problem}})
    async def submit_job(
        request: Request,
        seed: Annotated[int | None, Query(ge=0, le=2**31 - 1)] = None,
        basis: Annotated[str | None, Query(max_length=64)] = None,
    ) -> JSONResponse:
        """Body: a task spec (as the CLI's YAML/JSON files), or `{"spec": {...}, "seed": n,
        "basis": "<basis id>"}`. 202 with the job's URL in `Location`."""
        data = await _read_json(request, max_body)
        if isinstance(data, dict) and "spec" in data:
            extra = set(data) - {"spec", "seed", "basis"}
            if extra:
                raise ApiError(422, f"{sorted(extra)[0]}: unknown field (allowed: spec, seed, "
                                    "basis)")
            env_seed, env_basis = data.get("seed"), data.get("basis")
            if env_seed is not None and (not isinstance(env_seed, int) or isinstance(env_seed, bool)
                                         or not 0 <= env_seed < 2**31):
                raise ApiError(422, "seed: must be an integer in [0, 2^31)")
            if env_basis is not None and (not isinstance(env_basis, str) or len(env_basis) > 64):
                raise ApiError(422, "basis: must be a basis id (string)")
            seed = env_seed if env_seed is not None else seed
            basis = env_basis if env_basis is not None else basis
            data = data["spec"]
        try:
            spec = parse_spec(data, "spec")
        except SpecError as err:
            raise ApiError(422, str(err)) from None
        if basis is not None:
            from worker.driver import basis_from_record

            try:
                b = basis_from_record(repo.get_basis(basis))
            except NotFound:
                raise ApiError(422, f"basis: {basis!r} does not exist") from None
            try:
                b.check_spec(spec)
            except BasisError as err:
                raise ApiError(422, f"basis: {err}") from None
        try:  # the job's budget against the server's ceiling (worker.admission)
            budget = admission.check(spec, config, dimension=None if basis is None else b.k)
        except admission.BudgetExceeded as err:
            raise ApiError(422, str(err)) from None
        job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                              family=spec.family_name, task=spec.task_type,
                              seed=0 if seed is None else seed, basis_id=basis)
        if run_drivers:
            runner.submit(job.id)
        url = str(request.url_for("get_job", job_id=job.id))
        return JSONResponse({"id": job.id, "url": url, "status": job.status,
                             "budget": budget.to_dict()},
                            status_code=202, headers={"Location": url})

    @app.get("/jobs", response_model=schemas.JobPage, tags=["jobs"], summary="List jobs")
    def list_jobs(
        request: Request,
        status: Annotated[str | None, Query(description="one of " + ", ".join(JOB_STATUSES))]
        = None,
        family: Annotated[str | None, Query(max_length=100)] = None,
        limit: Annotated[int, Query(ge=1, le=200)] = 50,
        offset: Annotated[int, Query(ge=0)] = 0,
    ) -> dict[str, Any]:
        if status is not None and status not in JOB_STATUSES:
            raise ApiError(422, f"status: {status!r} is not one of {', '.join(JOB_STATUSES)}")
        items, total = repo.list_jobs(status=status, family=family, limit=limit, offset=offset)
        return {"items": [_job_out(j, request) for j in items], "total": total,
                "limit": limit, "offset": offset}

    def _job_cmrt(job_id: str, family: str) -> str | None:
        items, _ = repo.list_cmrts(family, limit=1000)
        return next((c.id for c in items if c.job_id == job_id), None)

    @app.get("/jobs/{job_id}", response_model=schemas.JobOut, tags=["jobs"], summary="One job",
             responses={404: {"model": schemas.Problem}})
    def get_job(job_id: str, request: Request) -> dict[str, Any]:
        job = repo.get_job(job_id)
        cmrt_id = _job_cmrt(job.id, job.family) if job.terminal else None
        out = _job_out(job, request, cmrt_id)
        out["spec"] = job.spec
        return out

    @app.get("/jobs/{job_id}/generations", response_model=schemas.GenerationPage, tags=["jobs"],
             summary="Generations after N (incremental polling)",
             responses={404: {"model": schemas.Problem}})
    def job_generations(
        job_id: str, after: Annotated[int, Query(ge=-1)] = -1,
        limit: Annotated[int, Query(ge=1, le=1000)] = 1000,
    ) -> dict[str, Any]:
        job = repo.get_job(job_id)
        gens = repo.generations(job_id, after=after)[:limit]
        return {"job_id": job_id, "status": job.status, "after": after,
                "last": gens[-1].iteration if gens else after,
                "generations": [_gen_out(g) for g in gens]}

    @app.get("/jobs/{job_id}/evaluations", tags=["jobs"],
             summary="Evaluation bookkeeping per generation (counts and attempts)",
             responses={404: {"model": schemas.Problem}})
    def job_evaluations(job_id: str) -> dict[str, Any]:
        job = repo.get_job(job_id)
        out = []
        for g in [-1, *range(job.iterations + 1)]:
            rows = repo.evaluations(job_id, g)
            if not rows:
                continue
            out.append({
                "generation": g,
                "population": len(rows),
                "done": sum(r.status == "done" for r in rows),
                "pending": sum(r.status == "pending" for r in rows),
                "failed": sum(r.status == "failed" for r in rows),
                "attempts": sum(r.attempts for r in rows),
                "repeated": sum(max(0, r.attempts - 1) for r in rows),
            })
        return {"job_id": job_id, "status": job.status, "generations": out}

    @app.post("/jobs/{job_id}/cancel", status_code=202, tags=["jobs"], summary="Cancel a job",
              responses={404: {"model": schemas.Problem}, 409: {"model": schemas.Problem}})
    def cancel_job(job_id: str, request: Request) -> JSONResponse:
        job = repo.get_job(job_id)
        if job.terminal:
            raise ApiError(409, f"job {job_id} already finished ({job.status})")
        job = repo.request_cancel(job_id)
        return JSONResponse({"id": job.id, "status": job.status,
                             "cancel_requested": job.cancel_requested,
                             "url": str(request.url_for("get_job", job_id=job.id))},
                            status_code=202)

    # ---- library ------------------------------------------------------------------------
    @app.get("/cmrts", tags=["library"], summary="Find CMRTs by task parameters",
             response_model=schemas.CmrtPage)
    def find_cmrts(
        request: Request,
        family: Annotated[str | None, Query(max_length=100)] = None,
        tolerance: Annotated[float | None, Query(ge=0, description="nearest within +-tolerance;"
                                                 " without it: exact match")] = None,
        limit: Annotated[int, Query(ge=1, le=200)] = 50,
        offset: Annotated[int, Query(ge=0)] = 0,
    ) -> dict[str, Any]:
        """`GET /cmrts?family=bend&duration=0.4[&tolerance=0.05]`: any other query key is a
        task parameter (e.g. duration, force). Nearest first when a tolerance is given."""
        params = _library_query(request)
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
        return {"items": [_cmrt_out(r, request) for r in items], "total": total,
                "limit": limit, "offset": offset}

    @app.get("/cmrts/interpolate", tags=["library"], summary="Interpolate a CMRT",
             responses={422: {"model": schemas.Problem}})
    def interpolate_cmrt(
        request: Request,
        family: Annotated[str, Query(max_length=100)],
        extrapolate: bool = False,
        along: Annotated[str | None, Query(max_length=64)] = None,
    ) -> dict[str, Any]:
        """`GET /cmrts/interpolate?family=bend&duration=0.5`: linear interpolation between the
        two library CMRTs nearest on either side; outside the stored range only with
        `extrapolate=true`. With several parameters, `along` names the interpolated one and
        the others must match exactly."""
        params = _library_query(request)
        if not params:
            raise ApiError(422, "a task parameter to interpolate at is required, e.g. duration=0.5")
        if along is None:
            if len(params) > 1:
                raise ApiError(422, "along: required when several task parameters are given")
            along = next(iter(params))
        if along not in params:
            raise ApiError(422, f"along: {along!r} is not among the given parameters")
        value = params.pop(along)
        try:
            out = interpolate_library(repo, family, along, value, filters=params,
                                      extrapolate=extrapolate)
        except InterpolationError as err:
            raise ApiError(422, str(err)) from None
        for n in out["neighbours"]:
            n["url"] = str(request.url_for("get_cmrt", cmrt_id=n["id"]))
        return out

    @app.get("/cmrts/{cmrt_id}", tags=["library"], summary="One CMRT with its curve",
             responses={404: {"model": schemas.Problem}})
    def get_cmrt(cmrt_id: str, request: Request) -> dict[str, Any]:
        return _cmrt_out(repo.get_cmrt(cmrt_id), request, full=True)

    # ---- bases ----------------------------------------------------------------------------
    @app.post("/bases", status_code=201, tags=["library"], summary="Build a PCA basis",
              responses={400: {"model": schemas.Problem}, 422: {"model": schemas.Problem}})
    async def create_basis(request: Request) -> JSONResponse:
        """Body `{"family": "bend", "k": 3}`: PCA of the family's library CMRTs."""
        data = await _read_json(request, max_body)
        try:
            req = schemas.BasisRequest.model_validate(data)
        except Exception as err:  # pydantic ValidationError
            errs = getattr(err, "errors", lambda: [])()
            msg = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'body'}: {e['msg']}" for e in errs)
            raise ApiError(422, msg or str(err)) from None
        try:
            basis_id = build_library_basis(repo, req.family, req.k)
        except BasisError as err:
            raise ApiError(422, str(err)) from None
        url = str(request.url_for("get_basis", basis_id=basis_id))
        body = _basis_out(repo.get_basis(basis_id), url)
        return JSONResponse(json.loads(json.dumps(body, default=str)), status_code=201,
                            headers={"Location": url})

    def _basis_out(b: Any, url: str) -> dict[str, Any]:
        return {"id": b.id, "url": url, "family": b.family, "k": b.k, "mean": b.mean,
                "components": b.components, "variance_explained": b.variance_explained,
                "members": b.members, "box": b.box, "created_at": b.created_at}

    @app.get("/bases/{basis_id}", tags=["library"], summary="One PCA basis",
             responses={404: {"model": schemas.Problem}})
    def get_basis(basis_id: str, request: Request) -> dict[str, Any]:
        return _basis_out(repo.get_basis(basis_id),
                          str(request.url_for("get_basis", basis_id=basis_id)))

    # ---- operations -----------------------------------------------------------------------
    @app.get("/health", tags=["operations"], summary="Database and broker health")
    def health() -> JSONResponse:
        checks: dict[str, Any] = {}
        ok = True
        try:
            repo.list_jobs(limit=1)
            checks["database"] = "ok"
        except Exception as err:  # noqa: BLE001
            ok, checks["database"] = False, f"error: {type(err).__name__}: {err}"
        if isinstance(executor, CeleryExecutor):
            try:
                executor.ping(timeout=2.0)
                checks["broker"] = "ok"
            except Exception as err:  # noqa: BLE001
                ok, checks["broker"] = False, f"error: {type(err).__name__}: {err}"
        else:
            checks["broker"] = "none (embedded local process pool)"
        checks["executor"] = executor.kind
        checks["drivers"] = len(runner.active)
        return JSONResponse({"status": "ok" if ok else "degraded", **checks},
                            status_code=200 if ok else 503)

    @app.get("/dashboard", response_class=HTMLResponse, tags=["operations"],
             summary="Convergence dashboard (HTML)")
    def dashboard() -> HTMLResponse:
        html = resources.files("service").joinpath("static/dashboard.html").read_text()
        return HTMLResponse(html)

    @app.get("/", tags=["operations"], include_in_schema=False)
    def index(request: Request) -> dict[str, Any]:
        return {"service": "cmrt", "openapi": str(request.url_for("openapi")),
                "docs": "/docs", "dashboard": str(request.url_for("dashboard")),
                "jobs": str(request.url_for("list_jobs")),
                "cmrts": str(request.url_for("find_cmrts"))}

    return app
