"""HTTP errors of the API and their translation from domain exceptions.

Every error body is `{"detail": "<field>: <rule>"}` (`schemas.Problem`): 400 malformed JSON,
401 missing or wrong API token, 403 a state-changing request from another origin
(`service.security`), 404 unknown id (quoted, ASCII-escaped), 409 conflicting state, 413 body
too large,
415 body not `application/json`, 422 a field breaking a rule, 503 the database unreachable
(with `Retry-After`). Domain exceptions (store.NotFound, pydantic and FastAPI validation errors,
SQLAlchemy's connection errors) are translated here, at the HTTP edge, and nowhere else.

A database outage (the server down, refusing connections, a session terminated, the pool
exhausted) answers 503 `{"detail": "database: unreachable; retry later"}` with `Retry-After`:
the request's transaction did not commit, so nothing of it is stored, and repeating it later is
safe. What the driver said goes to the log only (it may quote SQL or the database's address).
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError

from application.errors import ApplicationError, Busy, validation_message
from store import NotFound

log = logging.getLogger("cmrt.service.errors")

#: Seconds a client is asked to wait after a 503 for an unreachable database.
DATABASE_RETRY_AFTER_S = 5
DATABASE_UNREACHABLE = "database: unreachable; retry later"


def database_unreachable(err: BaseException) -> bool:
    """Whether `err` means the database cannot be reached (rather than a bad statement)."""
    if isinstance(err, OperationalError | InterfaceError | PoolTimeoutError):
        return True
    return isinstance(err, DBAPIError) and bool(err.connection_invalidated)


class HttpError(Exception):
    """An HTTP error with the message the client gets as `detail`."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(HttpError)
    async def _http_error(_: Request, err: HttpError) -> JSONResponse:
        return JSONResponse({"detail": err.detail}, status_code=err.status, headers=err.headers)

    @app.exception_handler(ApplicationError)
    async def _refused(_: Request, err: ApplicationError) -> JSONResponse:
        headers = {"Retry-After": str(err.retry_after)} if isinstance(err, Busy) else None
        return JSONResponse({"detail": err.message}, status_code=err.http_status,
                            headers=headers)

    @app.exception_handler(NotFound)
    async def _not_found(_: Request, err: NotFound) -> JSONResponse:
        return JSONResponse({"detail": str(err)}, status_code=404)

    async def _database(request: Request, err: Exception) -> JSONResponse:
        if not database_unreachable(err):
            raise err
        log.error("database unreachable on %s %s: %s", request.method, request.url.path,
                  str(err).splitlines()[0] if str(err) else type(err).__name__)
        return JSONResponse({"detail": DATABASE_UNREACHABLE}, status_code=503,
                            headers={"Retry-After": str(DATABASE_RETRY_AFTER_S)})

    app.add_exception_handler(DBAPIError, _database)
    app.add_exception_handler(PoolTimeoutError, _database)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, err: RequestValidationError) -> JSONResponse:
        msg = validation_message(err.errors(), drop=("query", "path", "body", "header"))
        return JSONResponse({"detail": msg or "request: invalid"}, status_code=422)
