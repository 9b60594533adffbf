"""What the application refuses, and how each edge says so.

Every refusal of a use case is an `ApplicationError`; its class carries the HTTP status the
service answers with and the exit status the command line ends with, so each edge maps the
whole tree once (`service.errors`, `cli.main`) and no edge knows a domain error type. A use case
that calls the domain (a spec parsed, a family checked, a CMRT interpolated) turns the domain's
error into one of these, its message naming the field and the rule (`field: rule`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

from sim.spec import error_location

#: The command line's exit status for input it refuses (argparse's own).
EXIT_BAD_INPUT = 2
#: The command line's exit status for a temporary failure (BSD's EX_TEMPFAIL): retry later.
EXIT_TEMPORARY = 75


class ApplicationError(Exception):
    """A request the application refuses; the message is `field: rule`."""

    http_status: ClassVar[int] = 422
    exit_code: ClassVar[int] = EXIT_BAD_INPUT

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InvalidRequest(ApplicationError):  # noqa: N818 - the name says what it is
    """A field breaks a rule (HTTP 422, exit 2)."""


class Missing(ApplicationError):  # noqa: N818
    """What the request names (a family, a basis, a job, a character) does not exist
    (HTTP 404, exit 2)."""

    http_status = 404


class RequestConflict(ApplicationError):  # noqa: N818
    """The request conflicts with what is stored (a name taken, a job finished) (HTTP 409,
    exit 2)."""

    http_status = 409


class Busy(ApplicationError):  # noqa: N818
    """Every process that could serve the request is busy; retry after `retry_after` seconds
    (HTTP 503 with Retry-After, exit 75)."""

    http_status = 503
    exit_code = EXIT_TEMPORARY

    def __init__(self, message: str, retry_after: int = 1) -> None:
        super().__init__(message)
        self.retry_after = retry_after


def validation_message(errors: Iterable[Mapping[str, Any]], drop: tuple[str, ...] = ()) -> str:
    """One line naming each failing field (as a spec's author wrote it: `sim.spec.
    error_location`) and its rule, from pydantic's `errors()` list; the parts of a path in
    `drop` (an edge's `body`, `query`) are left out."""
    parts = []
    for e in errors:
        loc = ".".join(str(p) for p in error_location(e["loc"]) if p not in drop)
        parts.append(f"{loc or 'body'}: {e['msg'].removeprefix('Value error, ')}")
    return "; ".join(parts)


__all__ = ["EXIT_BAD_INPUT", "EXIT_TEMPORARY", "ApplicationError", "Busy", "InvalidRequest",
           "Missing", "RequestConflict", "validation_message"]
