"""Reading a JSON request body at the boundary: size limit, nesting limit, finite numbers.

`read_json` refuses, before any recursive work is done on the body: more than
`Settings.max_body_bytes` bytes (413), nesting deeper than `MAX_JSON_DEPTH` arrays/objects (400,
checked by a flat scan, so a body of 100,000 `[` never reaches the recursive parser), malformed
JSON (400, `NaN`/`Infinity` included), and numbers that overflow a double such as `1e999` (422
naming the field).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from typing import Any, TypeVar

from fastapi import Request
from pydantic import BaseModel, ValidationError

from application.errors import validation_message
from service.errors import HttpError

M = TypeVar("M", bound=BaseModel)

#: Deepest nesting of JSON arrays/objects accepted in a request body (a task spec needs ~6).
MAX_JSON_DEPTH = 64

_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_BRACKETS = re.compile(rb"[\[\]{}]")


def json_depth(body: bytes, limit: int = MAX_JSON_DEPTH) -> int:
    """Deepest array/object nesting of a JSON text, without parsing it; stops counting once
    past `limit` (returns limit + 1). Brackets inside strings do not count."""
    depth = deepest = 0
    for m in _BRACKETS.finditer(_STRING.sub(b'""', body)):
        if m.group() in (b"[", b"{"):
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest > limit:
                    return deepest
        else:
            depth -= 1
    return deepest


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def non_finite_path(value: Any, path: str = "") -> str | None:
    """Dotted path of the first non-finite float inside a parsed JSON value, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (path or "body")
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = non_finite_path(v, f"{path}.{k}" if path else str(k))
        if found is not None:
            return found
    return None


def parse_json(body: bytes, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """Parse a request body (see the module docstring for what is refused)."""
    if not body.strip():
        raise HttpError(400, "body: malformed JSON: the request body is empty")
    if json_depth(body, max_depth) > max_depth:
        raise HttpError(400, f"body: JSON nested deeper than {max_depth} levels "
                            "(arrays/objects) is refused")
    try:
        data = json.loads(body, parse_constant=_reject_constant)
    except (ValueError, UnicodeDecodeError) as err:
        raise HttpError(400, f"body: malformed JSON: {err}") from None
    except RecursionError:  # pragma: no cover - the depth scan refuses such bodies first
        raise HttpError(400, f"body: JSON nested deeper than {max_depth} levels") from None
    bad = non_finite_path(data)
    if bad is not None:
        raise HttpError(422, f"{bad}: must be a finite number (the value overflows a double)")
    return data


def require_json_content_type(request: Request) -> None:
    """415 unless the body is declared `application/json` (a cross-origin page can send
    `text/plain` without a CORS preflight, never `application/json`)."""
    raw = request.headers.get("content-type")
    media = (raw or "").split(";", 1)[0].strip().lower()
    if media != "application/json":
        got = f"{raw!r}" if raw else "none"
        raise HttpError(415, f"content-type: must be application/json, got {got}")


async def read_json(request: Request, limit: int, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """The request body as JSON: 415 unless declared application/json, 413 over `limit` bytes,
    the rest as in `parse_json`."""
    require_json_content_type(request)
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise HttpError(413, f"body: {declared} bytes exceed the limit of {limit} bytes")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise HttpError(413, f"body: exceeds the limit of {limit} bytes")
    return parse_json(bytes(body), max_depth)


async def read_model(request: Request, model: type[M], limit: int,
                     prepare: Callable[[Any], Any] | None = None) -> M:
    """The request body parsed (as `read_json`), given to `prepare` if any (e.g. a stored
    character put into its spec), and validated into `model`; a field breaking a rule is a
    422 naming every such field and its rule."""
    data = await read_json(request, limit)
    if prepare is not None:
        data = prepare(data)
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise HttpError(422, validation_message(err.errors())) from None
