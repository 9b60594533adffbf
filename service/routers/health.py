"""`/health`: is the database (and the broker, in distributed mode) reachable."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from service.deps import ServicesDep
from service.openapi import error_responses
from worker.executors import CeleryExecutor

router = APIRouter(tags=["operations"])
log = logging.getLogger("cmrt.service.health")


def _check(name: str, probe: Callable[[], Any]) -> str:
    """"ok", or "error" with the exception in the log only."""
    try:
        probe()
    except Exception:  # noqa: BLE001 - any failure of a dependency is "error"
        log.exception("health: the %s check failed", name)
        return "error"
    return "ok"


@router.get("/health", summary="Database and broker health", responses=error_responses(503))
def health(svc: ServicesDep) -> JSONResponse:
    """`{"status": "ok" | "degraded", "database": "ok" | "error", "broker": ...}`: the state
    only; the error behind an "error" goes to the log (it may quote SQL or a URL)."""
    checks: dict[str, Any] = {"database": _check("database", lambda: svc.repo.list_jobs(limit=1))}
    if isinstance(svc.executor, CeleryExecutor):
        checks["broker"] = _check("broker", lambda: svc.executor.ping(timeout=2.0))
    else:
        checks["broker"] = "none (embedded local process pool)"
    ok = "error" not in checks.values()
    checks["executor"] = svc.executor.kind
    checks["drivers"] = len(svc.runner.active)
    return JSONResponse({"status": "ok" if ok else "degraded", **checks},
                        status_code=200 if ok else 503)
