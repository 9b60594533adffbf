"""`/characters`: character definitions kept by name, for specs to name as their
`character.model` (docs/characters.md)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request
from fastapi.responses import JSONResponse

from application import characters as app_characters
from service import schemas
from service.body import read_model
from service.deps import MAX_OFFSET, RepoDep, SettingsDep, url_for
from service.openapi import error_responses, json_body
from store import CharacterRecord

router = APIRouter(prefix="/characters", tags=["characters"])

CharacterName = Annotated[str, Path(pattern=app_characters.NAME_PATTERN)]


def _stored_out(rec: CharacterRecord, request: Request, definition: bool) -> dict[str, Any]:
    return {"name": rec.name, "url": url_for(request, "get_character", character_name=rec.name),
            "source": "stored", "summary": app_characters.summary(rec.name, rec.definition),
            "definition": rec.definition if definition else None,
            "definition_hash": rec.definition_hash, "created_at": rec.created_at}


@router.post("", status_code=201, summary="Keep a character definition by name",
             response_model=schemas.CharacterOut,
             openapi_extra=json_body(schemas.CharacterRequest,
                                     example=schemas.CHARACTER_EXAMPLE),
             responses=error_responses(400, 409, 413, 415, 422))
async def add_character(request: Request, repo: RepoDep, settings: SettingsDep
                        ) -> JSONResponse:
    """Body `{"name": "my_character", "definition": {...}}`: the definition is checked by
    every rule of a character file (422 naming the field and the rule; nothing is stored);
    409 when a shipped or stored character has the name. A spec then names it as its
    `character.model`, and the job it makes holds the definition."""
    req = await read_model(request, schemas.CharacterRequest, settings.max_body_bytes)
    rec = app_characters.add_character(repo, req.name, req.definition)
    body = schemas.CharacterOut.model_validate(_stored_out(rec, request, definition=True))
    return JSONResponse(body.model_dump(mode="json"), status_code=201,
                        headers={"Location": body.url})


@router.get("", response_model=schemas.CharacterPage, summary="List stored characters",
            responses=error_responses(422))
def list_characters(
    request: Request,
    repo: RepoDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
) -> dict[str, Any]:
    """Stored characters by name (their definitions at /characters/{name}), and the names of
    the shipped ones."""
    items, total = repo.list_characters(limit=limit, offset=offset)
    return {"items": [_stored_out(r, request, definition=False) for r in items],
            "total": total, "limit": limit, "offset": offset,
            "shipped": app_characters.shipped_names()}


@router.get("/{character_name}", response_model=schemas.CharacterOut, summary="One character",
            responses=error_responses(404))
def get_character(character_name: CharacterName, request: Request, repo: RepoDep) -> dict[str, Any]:
    """A stored character with its definition, or a shipped one's (a start for your own)."""
    name = character_name
    definition = app_characters.shipped(name)
    if definition is not None:
        return {"name": name, "url": url_for(request, "get_character", character_name=name),
                "source": "shipped", "summary": app_characters.summary(name, definition),
                "definition": definition}
    return _stored_out(repo.get_character(name), request, definition=True)
