"""`/health`: is the database (and the broker, in distributed mode) reachable."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from service.deps import ServicesDep
from worker.executors import CeleryExecutor

router = APIRouter(tags=["operations"])


@router.get("/health", summary="Database and broker health")
def health(svc: ServicesDep) -> JSONResponse:
    checks: dict[str, Any] = {}
    ok = True
    try:
        svc.repo.list_jobs(limit=1)
        checks["database"] = "ok"
    except Exception as err:  # noqa: BLE001
        ok, checks["database"] = False, f"error: {type(err).__name__}: {err}"
    if isinstance(svc.executor, CeleryExecutor):
        try:
            svc.executor.ping(timeout=2.0)
            checks["broker"] = "ok"
        except Exception as err:  # noqa: BLE001
            ok, checks["broker"] = False, f"error: {type(err).__name__}: {err}"
    else:
        checks["broker"] = "none (embedded local process pool)"
    checks["executor"] = svc.executor.kind
    checks["drivers"] = len(svc.runner.active)
    return JSONResponse({"status": "ok" if ok else "degraded", **checks},
                        status_code=200 if ok else 503)
