"""The OpenAPI document, made exact.

FastAPI's generated document is post-processed once (`install_openapi`):
- every error response (4xx/5xx) of every operation is documented with the body it really has,
  `schemas.Problem` (`{"detail": "<field>: <rule>"}`), instead of FastAPI's array of errors;
  each operation lists the codes it can answer (`ERRORS`, plus what `error_responses` adds);
- request bodies read by hand (`POST /jobs`, `POST /bases`) are documented from their models;
- pydantic's `$defs` are moved into `components/schemas` and every `#/$defs/X` reference is
  rewritten, so each `$ref` of the document resolves;
- made usable by client generators (openapi-python-client, tests/service/test_generated_client.py):
  operation ids are the router's tag and the function's name (`operation_id`, e.g.
  `jobs_cancel_job`), every schema name is unique (two models of one name are an error), and
  an object-valued property's default (`character: {...}`) moves into its description
  (`generator_friendly`: generators refuse a default on a property that is a model).
"""

from __future__ import annotations

import copy
import json
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from pydantic import BaseModel
from pydantic.json_schema import models_json_schema

from cmrt.settings import Settings
from service import schemas
from service.security import SAFE_METHODS, needs_token, token_of

REF_PREFIX = "#/components/schemas/"

#: What each error code means in this API (the description of its documented response).
ERRORS: dict[int, str] = {
    400: "A Host header that names no host of this service (service.security), malformed "
         "JSON, or JSON nested deeper than the limit (service.body.MAX_JSON_DEPTH)",
    401: "Missing or wrong API token (only when CMRT_API_TOKEN is set)",
    403: "A state-changing request from another origin (its Origin is not the service's, or "
         "Sec-Fetch-Site says cross-site or same-site)",
    404: "No such id",
    409: "The resource's state forbids it (e.g. cancelling a finished job)",
    413: "Request body larger than CMRT_MAX_BODY_BYTES",
    415: "Request body is not application/json",
    422: "A field breaks a rule; `detail` names the field and the rule",
    503: "The database is unreachable, every simulation process is busy, or (/health) a "
         "dependency is down; retry after `Retry-After` seconds",
}
#: Operations that read no database (every other one may answer 503 in an outage).
NO_DATABASE = frozenset({"/dashboard", "/docs", "/openapi.json", "/"})
_RETRY_AFTER = {"Retry-After": {"description": "seconds to wait before retrying",
                                "schema": {"type": "integer", "minimum": 1}}}
_PROBLEM = {"$ref": REF_PREFIX + "Problem"}


def operation_id(route: APIRoute) -> str:
    """The operation id of a route: its router's tag and its function's name
    (`jobs_cancel_job`), what a generated client names the call (FastAPI's default adds the
    path and method: `cancel_job_jobs__job_id__cancel_post`)."""
    return f"{route.tags[0]}_{route.name}" if route.tags else route.name


def generator_friendly(schemas_: dict[str, Any]) -> None:
    """Move the default of every property that is a model or a union of models (`{"$ref":
    ..., "default": {...}}`) into its description, in place: the default is still documented
    and still applied by the server, and generators that refuse a default on a model property
    (it would have to be built in the generated code) can read the schema."""
    for schema in schemas_.values():
        for prop in (schema.get("properties") or {}).values():
            if "type" not in prop and isinstance(prop.get("default"), dict):  # a model, or
                # a union of models (`controller`)
                default = json.dumps(prop.pop("default"), separators=(", ", ": "))
                text = prop.get("description", "").rstrip(".")
                prop["description"] = (f"{text}. " if text else "") + \
                    f"Default (when absent): {default}"


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """`responses=` of a route answering these error codes (besides the ones every route has)."""
    return {c: {"model": schemas.Problem, "description": ERRORS[c]} for c in codes}


def json_body(*models: type[BaseModel], example: Any, description: str = "") -> dict[str, Any]:
    """`openapi_extra=` documenting a body read by hand: one of `models`, as JSON."""
    refs = [{"$ref": REF_PREFIX + m.__name__} for m in models]
    schema = refs[0] if len(refs) == 1 else {"anyOf": refs}
    body = {"required": True,
            "content": {"application/json": {"schema": schema, "example": example}}}
    if description:
        body["description"] = description
    return {"requestBody": body, "x-body-models": [m.__name__ for m in models]}


#: OpenAPI links (what a response's ids open): (method, path, status) -> name -> (method, path,
#: parameters). Clients and schemathesis' stateful phase follow them.
LINKS: dict[tuple[str, str, str], dict[str, tuple[str, str, dict[str, str]]]] = {
    ("post", "/jobs", "202"): {
        "GetJob": ("get", "/jobs/{job_id}", {"job_id": "$response.body#/id"}),
        "JobGenerations": ("get", "/jobs/{job_id}/generations", {"job_id": "$response.body#/id"}),
        "JobEvaluations": ("get", "/jobs/{job_id}/evaluations", {"job_id": "$response.body#/id"}),
        "CancelJob": ("post", "/jobs/{job_id}/cancel", {"job_id": "$response.body#/id"}),
    },
    ("get", "/jobs", "200"): {
        "GetJob": ("get", "/jobs/{job_id}", {"job_id": "$response.body#/items/0/id"}),
    },
    ("post", "/characters", "201"): {
        "GetCharacter": ("get", "/characters/{character_name}",
                         {"character_name": "$response.body#/name"}),
    },
    ("post", "/bases", "201"): {
        "GetBasis": ("get", "/bases/{basis_id}", {"basis_id": "$response.body#/id"}),
    },
    ("get", "/cmrts", "200"): {
        "GetCmrt": ("get", "/cmrts/{cmrt_id}", {"cmrt_id": "$response.body#/items/0/id"}),
    },
}


def _add_links(doc: dict[str, Any]) -> None:
    for (method, path, status), links in LINKS.items():
        resp = doc["paths"][path][method]["responses"][status]
        resp["links"] = {
            name: {"operationId": doc["paths"][p][m]["operationId"], "parameters": params}
            for name, (m, p, params) in links.items()}


#: The NUL character is refused in every path and query value (service.deps.no_nul).
NO_NUL = "^[^\\u0000]*$"


def _forbid_nul(schema: dict[str, Any]) -> None:
    """Document `no_nul` on a parameter's string schema (or each string branch of anyOf)."""
    if schema.get("type") == "string" and "pattern" not in schema and "enum" not in schema:
        schema["pattern"] = NO_NUL
    for sub in schema.get("anyOf", []):
        _forbid_nul(sub)
    if schema.get("type") == "object":
        _forbid_nul(schema.get("propertyNames", {}))


def _hoist_defs(node: Any, into: dict[str, Any]) -> Any:
    """Move nested `$defs` into `into` and rewrite `#/$defs/X` refs (in place, returns node)."""
    if isinstance(node, dict):
        defs = node.pop("$defs", None)
        if defs:
            for name, sub in defs.items():
                sub = _hoist_defs(sub, into)
                if name in into and into[name] != sub:
                    raise ValueError(f"OpenAPI: two different schemas named {name!r}")
                into[name] = sub
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            node["$ref"] = REF_PREFIX + ref.removeprefix("#/$defs/")
        for v in node.values():
            _hoist_defs(v, into)
    elif isinstance(node, list):
        for v in node:
            _hoist_defs(v, into)
    return node


def _refs(node: Any) -> set[str]:
    if isinstance(node, dict):
        out = {node["$ref"]} if isinstance(node.get("$ref"), str) else set()
        for v in node.values():
            out |= _refs(v)
        return out
    if isinstance(node, list):
        return set().union(*(_refs(v) for v in node)) if node else set()
    return set()


def build_openapi(app: FastAPI, settings: Settings,
                  always: tuple[int, ...] = (400, 422)) -> dict[str, Any]:
    """The exact document of `app` under `settings` (see the module docstring). `always`:
    error codes every operation can answer (400: a Host that is not the service's, see
    service.security; 422: a NUL character in the path or query, see service.deps); every
    operation but the `NO_DATABASE` pages may answer 503 with `Retry-After` when the database
    is unreachable (service.errors). With an API token, the
    operations that need it say so (`security`, 401); state-changing ones answer 403 to
    requests from another origin (service.security)."""
    doc = get_openapi(title=app.title, version=app.version, description=app.description,
                      routes=app.routes)
    components = doc.setdefault("components", {}).setdefault("schemas", {})
    if token_of(settings):
        doc["components"]["securitySchemes"] = {
            "bearer": {"type": "http", "scheme": "bearer",
                       "description": "Authorization: Bearer <CMRT_API_TOKEN>"}}
    body_models: dict[str, type[BaseModel]] = {}
    for path, item in doc["paths"].items():
        for method, op in item.items():
            for name in op.pop("x-body-models", []):
                body_models[name] = getattr(schemas, name)
            codes = list(always)
            if path not in NO_DATABASE:
                codes.append(503)
            if method.upper() not in SAFE_METHODS:
                codes.append(403)
            if needs_token(settings, method, path):
                op["security"] = [{"bearer": []}]
                codes.append(401)
            for code in codes:
                op.setdefault("responses", {}).setdefault(
                    str(code), {"description": ERRORS[code]})
            for param in op.get("parameters", []):
                _forbid_nul(param.get("schema", {}))
            for code, resp in op.get("responses", {}).items():
                if int(code) >= 400:
                    resp["content"] = {"application/json": {"schema": copy.deepcopy(_PROBLEM)}}
                    if code == "503":
                        resp["headers"] = copy.deepcopy(_RETRY_AFTER)
                    if resp.get("description") in (None, "", "Validation Error"):
                        resp["description"] = ERRORS.get(int(code), "Error")
    if body_models:
        _, top = models_json_schema([(m, "validation") for m in body_models.values()],
                                    ref_template=REF_PREFIX + "{model}")
        for name, sub in top.get("$defs", {}).items():
            components.setdefault(name, sub)
    components.setdefault("Problem", schemas.Problem.model_json_schema())
    _add_links(doc)
    _hoist_defs(doc, components)
    used = _refs(doc["paths"])
    for unused in ("HTTPValidationError", "ValidationError"):
        if REF_PREFIX + unused not in used and unused in components:
            del components[unused]
    missing = {r for r in _refs(doc) if not (r.startswith(REF_PREFIX)
                                              and r.removeprefix(REF_PREFIX) in components)}
    if missing:
        raise ValueError(f"OpenAPI: unresolved references {sorted(missing)}")
    qualified = sorted(n for n in components if "__" in n)
    if qualified:  # pydantic names two models of one name by their module paths
        raise ValueError(f"OpenAPI: schema names {qualified} are not unique model names")
    generator_friendly(components)
    return doc


def install_openapi(app: FastAPI, settings: Settings) -> None:
    """Serve `build_openapi(app, settings)` at /openapi.json (built once, on first request)."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = build_openapi(app, settings)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
