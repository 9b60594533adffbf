"""Tunables of the distribution layer.

Shared settings (database and broker URLs, `CMRT_MAX_ATTEMPTS`, `CMRT_EVAL_TIME_LIMIT`,
`CMRT_LEASE_SECONDS`, `CMRT_WORKERS`) come from `cmrt.settings.get_settings()`, the one settings
factory; the few numbers only `worker/` needs are `CMRT_*` variables read here. Invariant
(checked): the evaluation time limit < Redis' visibility timeout, so Redis never re-delivers a
message whose task is still legitimately running.
"""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class _WorkerEnv(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="CMRT_", env_file=".env", extra="ignore")

    #: Redis re-delivers an unacknowledged message after this many seconds.
    visibility_timeout: float = Field(3600.0, gt=0)
    #: Job driver: longest wait between two polls of the store for finished evaluations
    #: (shorter near the expected end of a generation: worker.executors.PollSchedule).
    poll_interval: float = Field(0.2, gt=0)
    #: Job driver: when no evaluation of the generation finished for this long, the ones not done
    #: are dispatched again (idempotent), so a message lost with a broker restart never hangs a
    #: job. Default: the evaluation time limit + 60 s.
    stall_timeout: float | None = Field(None, gt=0)
    #: Job driver: a job fails once the broker has been unreachable for this long.
    broker_deadline: float = Field(120.0, gt=0)
    #: How often a runner looks for queued/running jobs without a live driver.
    scan_interval: float = Field(2.0, gt=0)
    #: Celery queue of evaluation tasks.
    queue: str = "cmrt"


class WorkerConfig:
    """Merged view: settings factory + worker-only variables."""

    def __init__(self, settings=None, **overrides) -> None:
        if settings is None:
            from cmrt.settings import get_settings

            settings = get_settings()
        env = _WorkerEnv()
        self.settings = settings
        self.database_url: str = settings.database_url
        self.broker_url: str | None = settings.broker_url
        self.result_backend: str | None = settings.result_backend or settings.broker_url
        self.max_attempts: int = settings.max_attempts
        self.task_time_limit: float = settings.eval_time_limit
        self.lease_ttl: float = settings.lease_seconds
        self.local_workers: int = settings.workers
        self.max_body_bytes: int = settings.max_body_bytes
        self.visibility_timeout: float = env.visibility_timeout
        self.poll_interval: float = env.poll_interval
        self.stall_timeout: float = env.stall_timeout or settings.eval_time_limit + 60.0
        self.broker_deadline: float = env.broker_deadline
        self.scan_interval: float = env.scan_interval
        self.queue: str = env.queue
        for k, v in overrides.items():
            if not hasattr(self, k):
                raise TypeError(f"unknown worker setting {k!r}")
            setattr(self, k, v)
        if self.task_time_limit >= self.visibility_timeout:
            raise ValueError(
                "CMRT_EVAL_TIME_LIMIT must be below CMRT_VISIBILITY_TIMEOUT "
                f"({self.task_time_limit:g} >= {self.visibility_timeout:g})"
            )

    @property
    def distributed(self) -> bool:
        return bool(self.broker_url)


@lru_cache(maxsize=1)
def get_worker_config() -> WorkerConfig:
    return WorkerConfig()
