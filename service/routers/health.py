"""`/health`: is the database (and the broker, in distributed mode) reachable."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from service.deps import ServicesDep
from service.openapi import error_responses
from worker.executors import CeleryExecutor

router = APIRouter(tags=["operations"])
log = logging.getLogger("cmrt.service.health")


@router.get("/health", summary="Database and broker health", responses=error_responses(503))
def health(svc: ServicesDep) -> JSONResponse:
    """`{"status": "ok" | "degraded", "database": "ok" | "error", "broker": ...}`: the state
    only; the error behind an "error" goes to the log (it may quote SQL or a URL)."""
    checks: dict[str, Any] = {}
    ok = True
    try:
        svc.repo.list_jobs(limit=1)
        checks["database"] = "ok"
    except Exception:  # noqa: BLE001
        log.exception("health: the database check failed")
        ok, checks["database"] = False, "error"
    if isinstance(svc.executor, CeleryExecutor):
        try:
            svc.executor.ping(timeout=2.0)
            checks["broker"] = "ok"
        except Exception:  # noqa: BLE001
            log.exception("health: the broker check failed")
            ok, checks["broker"] = False, "error"
    else:
        checks["broker"] = "none (embedded local process pool)"
    checks["executor"] = svc.executor.kind
    checks["drivers"] = len(svc.runner.active)
    return JSONResponse({"status": "ok" if ok else "degraded", **checks},
                        status_code=200 if ok else 503)
