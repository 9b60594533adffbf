"""`/health`: is the database (and the broker, in distributed mode) reachable, and do the
processes compute the same bits (their numeric fingerprints)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from service import schemas
from service.deps import ServicesDep
from service.errors import DATABASE_RETRY_AFTER_S
from service.openapi import error_responses
from worker.executors import CeleryExecutor
from worker.fingerprints import fingerprint_if_ready, live_fingerprints, redis_client

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


def _fingerprints(svc: Any, broker_ok: bool) -> dict[str, str]:
    """This process's numeric fingerprint ("api", once computed: the first call starts it in
    the background) and, with a reachable Redis broker, every live Celery worker's by hostname
    (worker.fingerprints)."""
    api = fingerprint_if_ready()
    out = {"api": api} if api else {}
    client = redis_client(svc.settings.broker_url or "") if broker_ok else None
    if client is not None:
        try:
            out.update(live_fingerprints(client))
        except Exception:  # noqa: BLE001 - the broker check above says whether Redis answers
            log.exception("health: reading the workers' fingerprints failed")
    return out


@router.get("/health", summary="Database and broker health", response_model=schemas.Health,
            responses=error_responses(503))
def health(svc: ServicesDep) -> JSONResponse:
    """`{"status": "ok" | "degraded", "database": "ok" | "error", "broker": ...,
    "fingerprints": {...}, "mixed": bool}`: the state only; the error behind an "error" goes to
    the log (it may quote SQL or a URL). `fingerprints`: the numeric fingerprint of this process
    ("api") and of every live Celery worker; `mixed`: more than one. Degraded: 503 with
    `Retry-After` and a `detail` naming what is unreachable."""
    checks: dict[str, Any] = {"database": _check("database", svc.repo.ping)}
    if isinstance(svc.executor, CeleryExecutor):
        checks["broker"] = _check("broker", lambda: svc.executor.ping(timeout=2.0))
    else:
        checks["broker"] = "none (embedded local process pool)"
    down = [k for k, v in checks.items() if v == "error"]
    checks["executor"] = svc.executor.kind
    checks["drivers"] = len(svc.runner.active)
    checks["fingerprints"] = _fingerprints(svc, checks["broker"] == "ok")
    checks["mixed"] = len(set(checks["fingerprints"].values())) > 1
    if not down:
        return JSONResponse({"status": "ok", **checks})
    return JSONResponse({"status": "degraded", **checks,
                         "detail": "; ".join(f"{k}: unreachable" for k in down)},
                        status_code=503, headers={"Retry-After": str(DATABASE_RETRY_AFTER_S)})
