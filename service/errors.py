"""HTTP errors of the API and their translation from domain exceptions.

Every error body is `{"detail": "<field>: <rule>"}` (`schemas.Problem`): 400 malformed JSON,
401 missing or wrong API token, 403 a state-changing request from another origin
(`service.security`), 404 unknown id (quoted, ASCII-escaped), 409 conflicting state, 413 body
too large,
415 body not `application/json`, 422 a field breaking a rule. Domain exceptions (store.NotFound,
pydantic and FastAPI validation errors) are translated here, at the HTTP edge, and nowhere else.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from sim.spec import error_location
from store import NotFound


class ApiError(Exception):
    """An HTTP error with the message the client gets as `detail`."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


def validation_message(errors: Iterable[Mapping[str, Any]], drop: tuple[str, ...] = ()) -> str:
    """One line naming each failing field and its rule, from pydantic's `errors()` list."""
    parts = []
    for e in errors:
        loc = ".".join(str(p) for p in error_location(e["loc"]) if p not in drop)
        parts.append(f"{loc or 'body'}: {e['msg']}")
    return "; ".join(parts)


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(_: Request, err: ApiError) -> JSONResponse:
        return JSONResponse({"detail": err.detail}, status_code=err.status, headers=err.headers)

    @app.exception_handler(NotFound)
    async def _not_found(_: Request, err: NotFound) -> JSONResponse:
        return JSONResponse({"detail": str(err)}, status_code=404)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, err: RequestValidationError) -> JSONResponse:
        msg = validation_message(err.errors(), drop=("query", "path", "body", "header"))
        return JSONResponse({"detail": msg or "request: invalid"}, status_code=422)
