"""Replays: the self-contained HTML player (`service.replay_page`) or its JSON document
(`sim.replay`, docs/replay.md) of a library CMRT on its own task, of a job's best candidate so
far, or of a what-if clip; each with the clip without anticipation (flat spline) beside it.

The clips are simulated in the API's simulation pool (`application.simulations.run_replay`), like
`POST /simulations`. 404: unknown id; 409: a job without a best candidate yet, a CMRT stored
without its spec, or a stored candidate whose clip fails; 422: a bad body or parameter;
503: every simulation process is busy.

A job's motion files, `GET /jobs/{id}/motion.bvh` and `.csv` (`sim.export`, docs/export.md):
the best candidate so far simulated once in the same pool (`run_export`) and written at
`?fps=` (default 60, 1-1000); 404 while the job has no candidate (there is no motion yet).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse, Response

from application.jobs import stored_job_spec
from application.simulations import SimulationBusyError, run_export, run_replay
from optim.errors import ParamsError
from optim.spline import check_params
from service import schemas
from service.body import read_model
from service.deps import ServicesDep, url_for
from service.errors import HttpError
from service.openapi import error_responses, json_body
from service.replay_page import render_replay, replay_csp
from service.routers.simulations import RETRY_AFTER_S, _params
from sim.errors import SpecError
from sim.export import DEFAULT_FPS, MAX_FPS, MIN_FPS
from sim.spec import TaskSpec, parse_spec

router = APIRouter(tags=["replays"])
log = logging.getLogger("cmrt.service.replays")

Compare = Annotated[bool, Query(description="also the clip without anticipation (flat "
                                            "spline), on the same timeline")]
# Documented for the HTML pages, checked by the HTTP edge (service.links), unused by the route.
Expires = Annotated[int | None, Query(ge=0, le=10**15, description="a signed link's expiry "
                                      "(unix seconds), from POST /links")]
Signature = Annotated[str | None, Query(max_length=64, pattern="^[0-9a-f]*$",
                                        description="a signed link's HMAC, from POST /links")]
Fps = Annotated[float, Query(ge=MIN_FPS, le=MAX_FPS, allow_inf_nan=False,
                             description="frames per second, resampled from the 1 kHz "
                                         "simulation")]
#: The motion files by extension: media type, and what they hold.
_MOTION = {"bvh": ("text/plain; charset=utf-8", "BVH: the character's skeleton"),
           "csv": ("text/csv; charset=utf-8", "CSV: root, joint angles, CM, CP")}
_HTML = {200: {"content": {"text/html": {"schema": {"type": "string"}}},
               "description": "The self-contained replay page (player, data and uPlot inline)"}}


async def _document(svc: Any, spec_data: dict[str, Any], params: list[float] | None,
                    about: dict[str, Any] | None, compare: bool, failed_status: int
                    ) -> dict[str, Any]:
    out = await _simulated(svc, "replay", failed_status, run_replay, spec_data, params, about,
                           compare)
    return out["replay"]


def _stored(load: Callable[[], TaskSpec], document: dict[str, Any], params: Any, what: str
            ) -> tuple[dict[str, Any], list[float]]:
    """A stored spec (its typed form from `load`) and parameter vector, checked (409 when they
    no longer fit); the stored document (the canonical dump of the spec) goes to the
    simulation pool as it is."""
    try:
        checked = check_params(load(), params)
    except (SpecError, ParamsError) as err:
        raise HttpError(409, f"{what}: cannot be replayed ({err})") from None
    return document, [float(v) for v in checked]


async def _cmrt_doc(cmrt_id: str, request: Request, svc: Any, compare: bool) -> dict[str, Any]:
    rec = svc.repo.get_cmrt(cmrt_id)  # store.NotFound: 404
    if rec.spec is None:
        raise HttpError(409, f"cmrt {cmrt_id!r}: stored without its task spec; it cannot be "
                            "replayed on its own task")
    what = f"cmrt {cmrt_id!r}"
    spec, params = _stored(lambda: parse_spec(rec.spec, what), rec.spec, rec.params, what)
    about = {"source": "library", "id": rec.id, "objective": rec.objective,
             "url": url_for(request, "get_cmrt", cmrt_id=rec.id)}
    return await _document(svc, spec, params, about, compare, 409)


async def _job_doc(job_id: str, request: Request, svc: Any, compare: bool) -> dict[str, Any]:
    job = svc.repo.get_job(job_id)  # store.NotFound: 404
    if job.best_params is None:
        raise HttpError(409, f"job {job_id!r}: no best candidate yet ({job.status})")
    # the job's spec by its hash: parsed once per process, not at every replay
    spec, params = _stored(lambda: stored_job_spec(job).spec, job.spec, job.best_params,
                           f"job {job_id!r}")
    about = {"source": "job", "id": job.id, "job_status": job.status,
             "job_objective": job.best_objective,
             "url": url_for(request, "get_job", job_id=job.id)}
    return await _document(svc, spec, params, about, compare, 409)


async def _simulated(svc: Any, what: str, failed_status: int, fn: Any, *args: Any
                     ) -> dict[str, Any]:
    """`fn(*args)` in the simulation pool: its `done` answer, or 503 (every process busy) or
    `failed_status` naming `what` failed and why."""
    try:
        out = await svc.simulations.call(fn, *args)
    except SimulationBusyError:
        raise HttpError(503, "simulations: every simulation process is busy; retry later",
                       headers={"Retry-After": str(RETRY_AFTER_S)}) from None
    if out["status"] != "done":
        raise HttpError(failed_status, f"{what}: the simulation failed ({out['error']})")
    return out


async def _job_motion(job_id: str, svc: Any, fmt: str, fps: float) -> Response:
    """The job's best candidate's clip as a motion file (404 while it has none)."""
    job = svc.repo.get_job(job_id)  # store.NotFound: 404
    if job.best_params is None:
        raise HttpError(404, f"job {job_id!r}: no best candidate yet ({job.status}); its "
                             "motion exists once a candidate has been evaluated")
    spec, params = _stored(lambda: stored_job_spec(job).spec, job.spec, job.best_params,
                           f"job {job_id!r}")
    out = await _simulated(svc, "motion", 409, run_export, spec, params, fmt, fps)
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", str(job.name or "job"))[:64]
    return Response(out["text"], media_type=_MOTION[fmt][0], headers={
        "content-disposition": f'attachment; filename="{name}-{job.id}.{fmt}"'})


async def _simulation_doc(request: Request, svc: Any) -> dict[str, Any]:
    req = await read_model(request, schemas.ReplayRequest, svc.settings.max_body_bytes)
    params, about = _params(svc, request, req)
    return await _document(svc, req.spec.model_dump(mode="json"), params, about, req.compare,
                           422)


def _html(doc: dict[str, Any]) -> HTMLResponse:
    return HTMLResponse(render_replay(doc), headers={"content-security-policy": replay_csp()})


@router.get("/cmrts/{cmrt_id}/replay", response_class=HTMLResponse, responses={
    **_HTML, **error_responses(404, 409, 503)}, summary="Replay a library CMRT (HTML player)")
async def cmrt_replay(cmrt_id: str, request: Request, svc: ServicesDep,
                      compare: Compare = True, expires: Expires = None,
                      signature: Signature = None) -> HTMLResponse:
    """The CMRT on its own task (its stored spec), beside the clip without anticipation."""
    return _html(await _cmrt_doc(cmrt_id, request, svc, compare))


@router.get("/cmrts/{cmrt_id}/replay.json", response_model=schemas.ReplayOut,
            responses=error_responses(404, 409, 503), summary="Replay a library CMRT (JSON)")
async def cmrt_replay_json(cmrt_id: str, request: Request, svc: ServicesDep,
                           compare: Compare = True) -> JSONResponse:
    return JSONResponse(await _cmrt_doc(cmrt_id, request, svc, compare))


@router.get("/jobs/{job_id}/replay", response_class=HTMLResponse, responses={
    **_HTML, **error_responses(404, 409, 503)},
    summary="Replay a job's best candidate so far (HTML player)")
async def job_replay(job_id: str, request: Request, svc: ServicesDep,
                     compare: Compare = True, expires: Expires = None,
                     signature: Signature = None) -> HTMLResponse:
    """The job's best candidate so far on the job's spec, beside the clip without
    anticipation; 409 while the job has no candidate yet."""
    return _html(await _job_doc(job_id, request, svc, compare))


@router.get("/jobs/{job_id}/replay.json", response_model=schemas.ReplayOut,
            responses=error_responses(404, 409, 503),
            summary="Replay a job's best candidate so far (JSON)")
async def job_replay_json(job_id: str, request: Request, svc: ServicesDep,
                          compare: Compare = True) -> JSONResponse:
    return JSONResponse(await _job_doc(job_id, request, svc, compare))


@router.post("/simulations/replay", response_class=HTMLResponse, responses={
    **_HTML, **error_responses(400, 413, 415, 422, 503)},
    openapi_extra=json_body(schemas.ReplayRequest, example=schemas.REPLAY_EXAMPLE),
    summary="Replay a what-if clip (HTML player)")
async def simulation_replay(request: Request, svc: ServicesDep) -> HTMLResponse:
    """Body `{"spec": {...}, "cmrt": <as POST /simulations> | null, "compare": true}`; a clip
    that fails (diverges, times out) is a 422 naming the reason."""
    return _html(await _simulation_doc(request, svc))


@router.post("/simulations/replay.json", response_model=schemas.ReplayOut, responses=
             error_responses(400, 413, 415, 422, 503),
             openapi_extra=json_body(schemas.ReplayRequest, example=schemas.REPLAY_EXAMPLE),
             summary="Replay a what-if clip (JSON)")
async def simulation_replay_json(request: Request, svc: ServicesDep) -> JSONResponse:
    return JSONResponse(await _simulation_doc(request, svc))


def _motion_responses(fmt: str) -> dict[int | str, dict[str, Any]]:
    media, what = _MOTION[fmt]
    return {200: {"content": {media.split(";")[0]: {"schema": {"type": "string"}}},
                  "description": f"The motion file ({what}), as an attachment"},
            **error_responses(404, 409, 422, 503)}


@router.get("/jobs/{job_id}/motion.bvh", response_class=Response,
            responses=_motion_responses("bvh"),
            summary="A job's best candidate's motion as BVH (the character's skeleton)")
async def job_motion_bvh(job_id: str, svc: ServicesDep, fps: Fps = DEFAULT_FPS,
                         expires: Expires = None, signature: Signature = None) -> Response:
    """The job's best candidate so far, simulated on the job's spec, as BVH at `fps` frames
    per second (docs/export.md); 404 while the job has no candidate."""
    return await _job_motion(job_id, svc, "bvh", fps)


@router.get("/jobs/{job_id}/motion.csv", response_class=Response,
            responses=_motion_responses("csv"),
            summary="A job's best candidate's motion as CSV (root, joint angles, CM, CP)")
async def job_motion_csv(job_id: str, svc: ServicesDep, fps: Fps = DEFAULT_FPS,
                         expires: Expires = None, signature: Signature = None) -> Response:
    """The job's best candidate so far, simulated on the job's spec, as CSV at `fps` frames
    per second (docs/export.md); 404 while the job has no candidate."""
    return await _job_motion(job_id, svc, "csv", fps)
