"""The one settings module: every process (CLI, API, job drivers, Celery workers) reads its
configuration from `CMRT_*` variables through `get_settings()`; nothing else reads them.

Nothing is built at import time; call `get_settings()` (cached per process) or construct
`Settings(...)` directly (tests, tools). Environment variables (and a `.env` file in the working
directory, if present):

========================  ==========================================  =========================
variable                  meaning                                     default
========================  ==========================================  =========================
CMRT_DATA_DIR             folder for the embedded database, results   ./cmrt-data
CMRT_DATABASE_URL         SQLAlchemy URL                              sqlite:///<data_dir>/cmrt.db
CMRT_BROKER_URL           Celery broker; unset = local process pool   None
CMRT_RESULT_BACKEND       Celery result backend                       None
CMRT_WORKERS              local pool size / default job workers       2
CMRT_MAX_ATTEMPTS         attempts per candidate before the job fails 3
CMRT_EVAL_TIME_LIMIT      seconds per candidate evaluation            600
CMRT_LEASE_SECONDS        driver lease time-to-live, seconds          30
CMRT_API_HOST             HTTP bind address                           127.0.0.1
CMRT_API_PORT             HTTP port                                   8000
CMRT_MAX_BODY_BYTES       largest accepted request body               1000000
CMRT_VISIBILITY_TIMEOUT   Redis re-delivers an unacked message after  3600 (s)
CMRT_POLL_INTERVAL        driver: longest wait between store polls    0.2 (s)
CMRT_STALL_TIMEOUT        driver: re-send unresolved candidates after  eval_time_limit + 60 (s)
                          this long without a finished evaluation
CMRT_BROKER_DEADLINE      driver: fail the job after the broker was   120 (s)
                          unreachable this long
CMRT_SCAN_INTERVAL        runner: look for orphaned jobs every        2 (s)
CMRT_QUEUE                Celery queue of evaluation tasks            cmrt
CMRT_WORKER_CONCURRENCY   `cmrt worker` processes                     None (the CPUs)
CMRT_LOG_LEVEL            log level of `cmrt serve` / `cmrt worker`   INFO
CMRT_MAX_JOB_SIM_SECONDS  ceiling of a job's budget (simulated s:     50000
                          evaluations x clip length; application.admission)
CMRT_DISPATCH_WINDOW      Celery: most unresolved evaluations one job 4
                          has in the queue at once (fair share)
CMRT_TASK_BATCH           Celery: most candidates per task            2
CMRT_API_TOKEN            bearer token the API requires; unset: open  None
CMRT_API_PUBLIC_READS     with a token: GET endpoints open too        false
CMRT_PUBLIC_URL           base of URLs the API returns; unset: paths  None
CMRT_ALLOWED_HOSTS        Host names the API answers besides          "" (loopback only)
                          loopback and the public URL's (comma-
                          separated; `*`: any, the check off)
CMRT_SIMULATION_WORKERS   API processes for POST /simulations clips   1
CMRT_API_DRIVERS          `cmrt serve` drives jobs and families;      true
                          false: `cmrt driver` processes do
CMRT_URL                  the service the client commands talk to     CMRT_PUBLIC_URL, else
                          (`cmrt submit/jobs/watch/library`)          http://<api_host>:<port>
========================  ==========================================  =========================

Invariant (checked): eval_time_limit < visibility_timeout, so Redis never re-delivers a message
whose task is still legitimately running.

The SQLite file's folder is created on demand by `store.db.make_engine`, never at import.
"""

from __future__ import annotations

import ipaddress
import re
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

DEFAULT_DATA_DIR = Path("./cmrt-data")
DB_FILE_NAME = "cmrt.db"
#: One entry of CMRT_ALLOWED_HOSTS without a colon: a DNS name or an IPv4 address (an entry
#: with a colon must be an IPv6 address, bare or in brackets); no scheme, port or path.
_HOST_NAME = re.compile(r"[a-z0-9_]([a-z0-9_-]*[a-z0-9_])?(\.[a-z0-9_]([a-z0-9_-]*[a-z0-9_])?)*\.?")


class Settings(BaseSettings):
    """Process configuration; see the module docstring for the environment variables."""

    model_config = SettingsConfigDict(
        env_prefix="CMRT_", env_file=".env", extra="ignore", validate_default=True
    )

    data_dir: Path = DEFAULT_DATA_DIR
    #: SQLAlchemy URL; None means an SQLite file `cmrt.db` under `data_dir` (filled in on load).
    database_url: str | None = None
    #: Celery broker (e.g. redis://host:6379/0); None selects the embedded local process pool.
    broker_url: str | None = None
    result_backend: str | None = None
    workers: Annotated[int, Field(ge=1, le=256)] = 2
    max_attempts: Annotated[int, Field(ge=1, le=100)] = 3
    eval_time_limit: Annotated[float, Field(gt=0.0)] = 600.0
    lease_seconds: Annotated[float, Field(gt=0.0)] = 30.0
    api_host: str = "127.0.0.1"
    api_port: Annotated[int, Field(ge=1, le=65535)] = 8000
    max_body_bytes: Annotated[int, Field(ge=1)] = 1_000_000
    #: Redis re-delivers an unacknowledged message after this many seconds.
    visibility_timeout: Annotated[float, Field(gt=0.0)] = 3600.0
    #: Job driver: longest wait between two polls of the store for finished evaluations
    #: (shorter near the expected end of a generation: worker.executors.PollSchedule).
    poll_interval: Annotated[float, Field(gt=0.0)] = 0.2
    #: Job driver: when no evaluation finished for this long, the unresolved ones are sent
    #: again (idempotent), so a message lost with a broker restart never hangs a job.
    #: None (default) means eval_time_limit + 60 s (filled in on load).
    stall_timeout: Annotated[float | None, Field(gt=0.0)] = None
    #: Job driver: a job fails once the broker has been unreachable for this long.
    broker_deadline: Annotated[float, Field(gt=0.0)] = 120.0
    #: How often a runner looks for queued/running jobs without a live driver.
    scan_interval: Annotated[float, Field(gt=0.0)] = 2.0
    #: Celery queue of evaluation tasks.
    queue: Annotated[str, Field(min_length=1, max_length=200)] = "cmrt"
    #: Processes of a `cmrt worker` (None: one per CPU).
    worker_concurrency: Annotated[int | None, Field(ge=1, le=256)] = None
    #: Ceiling of one job's budget in simulated seconds (application.admission): above it a job is
    #: refused (422).
    max_job_sim_seconds: Annotated[float, Field(gt=0.0)] = 50_000.0
    #: Celery: the most evaluations of one job sent and not yet resolved at any time, so jobs
    #: share the queue (a small job waits behind at most this many of a large one's); about
    #: twice the evaluation processes keeps them all busy between the driver's polls.
    dispatch_window: Annotated[int, Field(ge=1, le=10_000)] = 4
    #: Celery: most candidates of one generation per evaluation task (fewer per-task costs in
    #: the broker and the worker; see worker.executors.plan_batches); 1: one task per candidate.
    task_batch: Annotated[int, Field(ge=1, le=1000)] = 2
    #: Log level of `cmrt serve` and `cmrt worker`.
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"] = "INFO"

    #: Bearer token of the HTTP API (`Authorization: Bearer <token>`); None: no authentication.
    api_token: SecretStr | None = None
    #: With a token: True leaves the read-only endpoints open to everyone, False closes them too.
    api_public_reads: bool = False
    #: Base of the absolute URLs the API returns (e.g. https://cmrt.example); None: the API
    #: returns paths (`/jobs/<id>`). Never taken from the request's Host header.
    public_url: Annotated[str | None, Field(pattern=r"^https?://[^\s/?#]+(/[^\s?#]*)?$")] = None

    #: Host names (the `Host` header, port ignored) the API answers besides the loopback names
    #: and addresses, the bind address and the public URL's host (service.security); a page
    #: whose DNS name was rebound to this machine sends its own name and is refused. Given as
    #: a comma-separated string (`CMRT_ALLOWED_HOSTS=cmrt.lan,api`); `*` turns the check off.
    allowed_hosts: Annotated[list[str], NoDecode] = []

    #: Processes of the API's own pool for what-if clips (POST /simulations).
    simulation_workers: Annotated[int, Field(ge=1, le=64)] = 1

    #: Whether `cmrt serve` drives jobs and families itself (the embedded default); false when
    #: `cmrt driver` processes of their own do, so the API can be scaled or restarted alone.
    api_drivers: bool = True

    #: The service `cmrt submit / jobs / watch / library` talk to (cmrt.client); None: the
    #: public URL, else this host's API address (`client_url`).
    url: Annotated[str | None, Field(pattern=r"^https?://[^\s/?#]+(/[^\s?#]*)?$")] = None

    @field_validator("worker_concurrency", mode="before")
    @classmethod
    def _zero_is_unset(cls, v: object) -> object:
        return None if v in (0, "0", "") else v

    @field_validator("allowed_hosts", mode="before")
    @classmethod
    def _comma_separated(cls, v: object) -> object:
        if isinstance(v, str):
            v = v.split(",")
        if isinstance(v, list | tuple):  # names compare case-insensitively; blanks are dropped
            return [h.strip().lower() if isinstance(h, str) else h for h in v
                    if not isinstance(h, str) or h.strip()]
        return v

    @field_validator("allowed_hosts")
    @classmethod
    def _host_names(cls, v: list[str]) -> list[str]:
        out = []
        for given in v:
            h = given
            if ":" in given:  # an IPv6 address, kept bare (as service.security compares it)
                try:
                    h = str(ipaddress.IPv6Address(given.removeprefix("[").removesuffix("]")))
                except ValueError:
                    h = ""
            elif given != "*" and not _HOST_NAME.fullmatch(given):
                h = ""
            if not h:
                raise ValueError(f"{given!r} is not a host name or address (no scheme, port "
                                 "or path; `*` for any)")
            out.append(h)
        return out

    @field_validator("log_level", mode="before")
    @classmethod
    def _upper(cls, v: object) -> object:
        return v.upper() if isinstance(v, str) else v

    @field_validator("api_token", "public_url", "url", mode="before")
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        return None if v == "" else v

    @model_validator(mode="after")
    def _defaults_and_invariants(self) -> Settings:
        if not self.database_url:
            self.database_url = f"sqlite:///{self.data_dir / DB_FILE_NAME}"
        if self.stall_timeout is None:
            self.stall_timeout = self.eval_time_limit + 60.0
        if self.eval_time_limit >= self.visibility_timeout:
            raise ValueError(
                "CMRT_EVAL_TIME_LIMIT must be below CMRT_VISIBILITY_TIMEOUT "
                f"({self.eval_time_limit:g} >= {self.visibility_timeout:g})"
            )
        return self

    @property
    def celery_result_backend(self) -> str | None:
        """The Celery result backend: CMRT_RESULT_BACKEND, else the broker."""
        return self.result_backend or self.broker_url

    @property
    def distributed(self) -> bool:
        """True when a Celery broker is configured (else: embedded local process pool)."""
        return bool(self.broker_url)

    @property
    def client_url(self) -> str:
        """Where the client commands find the service: CMRT_URL, else CMRT_PUBLIC_URL, else
        http://CMRT_API_HOST:CMRT_API_PORT (a wildcard bind address means this host)."""
        if self.url or self.public_url:
            return (self.url or self.public_url or "").rstrip("/")
        host = "127.0.0.1" if self.api_host in ("0.0.0.0", "", "::") else self.api_host
        if ":" in host:  # an IPv6 literal
            host = f"[{host}]"
        return f"http://{host}:{self.api_port}"



@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings, read from the environment on first call.

    `get_settings.cache_clear()` forgets them (tests that change the environment).
    """
    return Settings()
