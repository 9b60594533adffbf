"""HTML pages (the convergence dashboard) and the index `GET /`."""

from __future__ import annotations

from importlib import resources
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from service.deps import url_for

router = APIRouter(tags=["operations"])


def _page(name: str) -> HTMLResponse:
    return HTMLResponse(resources.files("service").joinpath("static", name).read_text())


@router.get("/dashboard", response_class=HTMLResponse, summary="Convergence dashboard (HTML)")
def dashboard() -> HTMLResponse:
    return _page("dashboard.html")


@router.get("/docs", response_class=HTMLResponse, include_in_schema=False)
def docs() -> HTMLResponse:
    """Swagger UI on /openapi.json, its assets served from service/static/swagger-ui (no CDN:
    it works offline)."""
    return _page("docs.html")


@router.get("/", include_in_schema=False)
def index(request: Request) -> dict[str, Any]:
    return {"service": "cmrt", "openapi": url_for(request, "openapi"),
            "docs": "/docs", "dashboard": url_for(request, "dashboard"),
            "jobs": url_for(request, "list_jobs"), "cmrts": url_for(request, "find_cmrts")}
