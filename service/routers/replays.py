"""Replays: the self-contained HTML player (`service.replay_page`) or its JSON document
(`sim.replay`, docs/replay.md) of a library CMRT on its own task, of a job's best candidate so
far, or of a what-if clip; each with the clip without anticipation (flat spline) beside it.

The clips are simulated in the API's simulation pool (`application.simulations`: `replay_cmrt`,
`replay_job`, `replay_whatif`), like `POST /simulations`. 404: unknown id; 409: a job without a
best candidate yet, a CMRT stored without its spec, or a stored candidate whose clip fails; 422:
a bad body or parameter; 503: every simulation process is busy.

A job's motion files, `GET /jobs/{id}/motion.bvh` and `.csv` (`sim.export`, docs/export.md):
the best candidate so far simulated once in the same pool (`application.simulations.job_motion`)
and written at `?fps=` (default 60, 1-1000); 404 while the job has no candidate (there is no
motion yet).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse, Response

from application import simulations
from application.simulations import DEFAULT_FPS, MAX_FPS, MIN_FPS
from service import schemas
from service.body import read_model
from service.deps import RequestLinks, ServicesDep
from service.openapi import error_responses, json_body
from service.replay_page import render_replay, replay_csp

router = APIRouter(tags=["replays"])

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


async def _cmrt_doc(cmrt_id: str, request: Request, svc: Any, compare: bool) -> dict[str, Any]:
    return await simulations.replay_cmrt(svc.repo, svc.simulations, RequestLinks(request),
                                         cmrt_id, compare)


async def _job_doc(job_id: str, request: Request, svc: Any, compare: bool) -> dict[str, Any]:
    return await simulations.replay_job(svc.repo, svc.simulations, RequestLinks(request),
                                        job_id, compare)


async def _simulation_doc(request: Request, svc: Any) -> dict[str, Any]:
    req = await read_model(request, schemas.ReplayRequest, svc.settings.max_body_bytes)
    return await simulations.replay_whatif(svc.repo, svc.simulations, RequestLinks(request),
                                           req)


async def _job_motion(job_id: str, svc: Any, fmt: Literal["bvh", "csv"], fps: float
                      ) -> Response:
    """The job's best candidate's clip as a motion file (404 while it has none)."""
    motion = await simulations.job_motion(svc.repo, svc.simulations, job_id, fmt, fps)
    return Response(motion.text, media_type=_MOTION[fmt][0], headers={
        "content-disposition": f'attachment; filename="{motion.filename}"'})


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
