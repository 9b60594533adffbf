"""POST /links: a signed, short-lived link to a replay page or a job's motion file
(`service.links`)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service import links, schemas
from service.body import read_model
from service.deps import RepoDep, SettingsDep
from service.openapi import error_responses, json_body
from service.security import token_of

router = APIRouter(prefix="/links", tags=["replays"])


@router.post("", status_code=201, summary="Sign a link to a replay page or a job's motion file",
             response_model=schemas.LinkOut,
             openapi_extra=json_body(schemas.LinkRequest, example=schemas.LINK_EXAMPLE),
             responses=error_responses(400, 404, 413, 415, 422))
async def create_link(request: Request, settings: SettingsDep, repo: RepoDep) -> JSONResponse:
    """Body `{"path": "/jobs/<id>/replay"}`: the path with `expires` and `signature` query
    parameters, which open the page without the `Authorization` header until `expires`
    (`LINK_SECONDS` from now). Without a configured token the plain path is returned. 404: no
    such job or library CMRT."""
    req = await read_model(request, schemas.LinkRequest, settings.max_body_bytes)  # signable
    kind, ident = req.path.split("/")[1:3]
    if kind == "jobs":  # store.NotFound: 404
        repo.get_job(ident)
    else:
        repo.get_cmrt(ident)
    token = token_of(settings)
    url, expires = links.sign(token, req.path) if token else (req.path, None)
    base = settings.public_url
    if base:
        url = f"{base.rstrip('/')}{url}"
    return JSONResponse({"url": url, "expires": expires}, status_code=201)
