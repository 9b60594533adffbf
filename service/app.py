"""The FastAPI app factory: `create_app()`.

The API process also hosts the job drivers (worker.runner.JobRunner, background threads): a job
is driven by whichever API process holds its lease, evaluations run in the local process pool
(embedded default: no broker configured) or on Celery workers (CMRT_BROKER_URL set). On start-up
the runner resumes queued/running jobs whose driver lease expired.

The routes live in `service.routers` (one router per resource) and get the settings,
repository, executor and runner through `service.deps`. Errors: see `service.errors`; nothing
is stored on a 4xx.
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager
from importlib import resources
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.staticfiles import StaticFiles

from application.simulations import SimulationPool
from cmrt.settings import Settings, get_settings
from service.deps import Services, no_nul
from service.errors import install_error_handlers
from service.openapi import install_openapi, operation_id
from service.routers import (
    bases,
    characters,
    cmrts,
    families,
    health,
    jobs,
    links,
    pages,
    refinements,
    replays,
    simulations,
)
from service.security import HttpEdge
from store import Repository, open_repository
from worker.executors import GenerationExecutor, make_generation_executor
from worker.runner import JobRunner

log = logging.getLogger("cmrt.service")


def create_app(
    settings: Settings | None = None,
    *,
    repo: Repository | None = None,
    executor: GenerationExecutor | None = None,
    run_drivers: bool | None = None,
) -> FastAPI:
    """Build the app. Defaults: settings from the environment (`cmrt.settings.get_settings`),
    repository migrated to the newest schema, executor chosen by the broker setting.
    `run_drivers=False` (default: `settings.api_drivers`): jobs and families are accepted and
    stored but driven elsewhere (`cmrt driver`), or not at all (HTTP-layer tests)."""
    settings = settings or get_settings()
    if run_drivers is None:
        run_drivers = settings.api_drivers
    repo = repo or open_repository(settings.database_url)
    executor = executor or make_generation_executor(settings)
    svc = Services(settings=settings, repo=repo, executor=executor,
                   runner=JobRunner(repo, executor, settings),
                   simulations=SimulationPool(settings.simulation_workers,
                                              settings.eval_time_limit),
                   run_drivers=run_drivers)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> Any:
        if run_drivers:
            svc.runner.start()
        yield
        svc.runner.stop(timeout=5)
        svc.executor.close()
        svc.simulations.close()

    app = FastAPI(
        title="CMRT service",
        version="0.1.0",
        description="Learns centre-of-mass reference trajectories (CMRTs) by CMA-ES over "
                    "physics simulations, and serves them from a library. See docs/service.md.",
        lifespan=lifespan,
        dependencies=[Depends(no_nul)],
        docs_url=None,  # service.routers.pages serves /docs from the project's own assets
        redoc_url=None,
        generate_unique_id_function=operation_id,
    )
    app.state.services = svc
    install_error_handlers(app)
    install_openapi(app, settings)
    for module in (jobs, families, cmrts, refinements, bases, characters, simulations, replays,
                   links, health, pages):
        app.include_router(module.router)
    static = resources.files("service").joinpath("static")
    app.mount("/static", StaticFiles(directory=str(static)), name="static")
    app.add_middleware(HttpEdge, app=app, settings=settings)
    return app
