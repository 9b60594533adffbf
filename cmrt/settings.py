"""The one settings factory: every process reads its configuration from `CMRT_*` variables.

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
CMRT_API_TOKEN            bearer token the API requires; unset: open  None
CMRT_API_PUBLIC_READS     with a token: GET endpoints open too        false
CMRT_PUBLIC_URL           base of URLs the API returns; unset: paths  None
CMRT_SIMULATION_WORKERS   API processes for POST /simulations clips   1
========================  ==========================================  =========================

The SQLite file's folder is created on demand by `store.db.make_engine` (or
`Settings.ensure_data_dir()`), never at import.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_DATA_DIR = Path("./cmrt-data")
DB_FILE_NAME = "cmrt.db"


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
    #: Bearer token of the HTTP API (`Authorization: Bearer <token>`); None: no authentication.
    api_token: SecretStr | None = None
    #: With a token: True leaves the read-only endpoints open to everyone, False closes them too.
    api_public_reads: bool = False
    #: Base of the absolute URLs the API returns (e.g. https://cmrt.example); None: the API
    #: returns paths (`/jobs/<id>`). Never taken from the request's Host header.
    public_url: Annotated[str | None, Field(pattern=r"^https?://[^\s/?#]+(/[^\s?#]*)?$")] = None

    #: Processes of the API's own pool for what-if clips (POST /simulations).
    simulation_workers: Annotated[int, Field(ge=1, le=64)] = 1

    @field_validator("api_token", "public_url", mode="before")
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        return None if v == "" else v

    @model_validator(mode="after")
    def _default_database(self) -> Settings:
        if not self.database_url:
            self.database_url = f"sqlite:///{self.data_dir / DB_FILE_NAME}"
        return self

    @property
    def distributed(self) -> bool:
        """True when a Celery broker is configured (else: embedded local process pool)."""
        return bool(self.broker_url)

    def ensure_data_dir(self) -> Path:
        """Create `data_dir` if needed and return it."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        return self.data_dir


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings, read from the environment on first call.

    `get_settings.cache_clear()` forgets them (tests that change the environment).
    """
    return Settings()
