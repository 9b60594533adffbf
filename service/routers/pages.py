"""HTML pages (the dashboard: jobs list, job page, library page; docs/service.md, "The
dashboard") and the index `GET /`.

The pages are static shells (no data in them, so no user text is ever templated into HTML):
their scripts under service/static/dash/ fetch the JSON endpoints and build the DOM with
textContent, and plot with the vendored uPlot (service/static/vendor/uplot)."""

from __future__ import annotations

from importlib import resources
from typing import Annotated, Any

from fastapi import APIRouter, Path, Request
from fastapi.responses import HTMLResponse

from service.deps import url_for

router = APIRouter(tags=["operations"])


def _page(name: str) -> HTMLResponse:
    return HTMLResponse(resources.files("service").joinpath("static", name).read_text())


@router.get("/dashboard", response_class=HTMLResponse, summary="Dashboard: the jobs (HTML)")
def dashboard() -> HTMLResponse:
    """Jobs with status, family, best objective, evaluations and elapsed time, filtered by
    status and family (it reads `GET /jobs`). `?job=ID` opens that job's page."""
    return _page("dash/jobs.html")


# The job and library pages are shells like /docs (no data in them), so like /docs they are
# left out of the OpenAPI document; their data endpoints are in it.
@router.get("/dashboard/jobs/{job_id}", response_class=HTMLResponse, include_in_schema=False)
def dashboard_job(job_id: Annotated[str, Path(max_length=64)]) -> HTMLResponse:
    """Live convergence, evaluations by state, stopping rule and best CMRT of one job (it
    reads `GET /jobs/{id}`, `.../generations?after=`, `.../evaluations?after=`, `.../best`).
    The shell is the same for any id; the page says when the job does not exist."""
    return _page("dash/job.html")


@router.get("/dashboard/library", response_class=HTMLResponse, include_in_schema=False)
def dashboard_library() -> HTMLResponse:
    """CMRTs by family and task parameter, overlaid, an interpolation preview and the PCA
    bases (it reads `GET /cmrts`, `/cmrts/{id}`, `/cmrts/interpolate`, `GET /bases`)."""
    return _page("dash/library.html")


@router.get("/dashboard/families/{family_id}", response_class=HTMLResponse,
            include_in_schema=False)
def dashboard_family(family_id: Annotated[str, Path(max_length=64)]) -> HTMLResponse:
    """One family: its runs and progress, the members' curves overlaid, and once done the
    checks beside the paper's Table 2 (it reads `GET /families/{id}?curves=true`)."""
    return _page("dash/family.html")


@router.get("/docs", response_class=HTMLResponse, include_in_schema=False)
def docs() -> HTMLResponse:
    """Swagger UI on /openapi.json, its assets served from service/static/swagger-ui (no CDN:
    it works offline)."""
    return _page("docs.html")


@router.get("/", include_in_schema=False)
def index(request: Request) -> dict[str, Any]:
    return {"service": "cmrt", "openapi": url_for(request, "openapi"),
            "docs": "/docs", "dashboard": url_for(request, "dashboard"),
            "library_page": url_for(request, "dashboard_library"),
            "jobs": url_for(request, "list_jobs"), "cmrts": url_for(request, "find_cmrts")}
