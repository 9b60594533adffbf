"""The settings factory: CMRT_* variables, defaults, nothing built at import."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmrt.settings import Settings, get_settings

VARS = (
    "DATA_DIR", "DATABASE_URL", "BROKER_URL", "RESULT_BACKEND", "WORKERS", "MAX_ATTEMPTS",
    "EVAL_TIME_LIMIT", "LEASE_SECONDS", "API_HOST", "API_PORT", "MAX_BODY_BYTES",
)  # fmt: skip


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    monkeypatch.chdir(tmp_path)  # no stray .env file
    for name in VARS:
        monkeypatch.delenv(f"CMRT_{name}", raising=False)
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


def test_defaults_embedded_mode(tmp_path: Path) -> None:
    s = Settings()
    assert s.database_url == "sqlite:///cmrt-data/cmrt.db"
    assert s.broker_url is None and not s.distributed
    assert (s.workers, s.max_attempts) == (2, 3)
    assert s.eval_time_limit > 0 and s.max_body_bytes > 0
    assert not (tmp_path / "cmrt-data").exists()  # created on demand only


def test_environment_variables(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("CMRT_DATA_DIR", str(tmp_path / "d"))
    monkeypatch.setenv("CMRT_WORKERS", "6")
    monkeypatch.setenv("CMRT_BROKER_URL", "redis://localhost:6379/0")
    monkeypatch.setenv("CMRT_API_PORT", "9000")
    s = get_settings()
    assert s.database_url == f"sqlite:///{tmp_path}/d/cmrt.db"
    assert s.workers == 6 and s.distributed and s.api_port == 9000
    assert get_settings() is s
    monkeypatch.setenv("CMRT_DATABASE_URL", "postgresql+psycopg://u@db/cmrt")
    get_settings.cache_clear()
    assert get_settings().database_url == "postgresql+psycopg://u@db/cmrt"


def test_bad_values_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CMRT_WORKERS", "0")
    with pytest.raises(ValueError, match="workers"):
        Settings()


def test_default_database_is_usable(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from store import open_repository

    monkeypatch.setenv("CMRT_DATA_DIR", str(tmp_path / "data"))
    repo = open_repository()
    try:
        assert repo.list_jobs() == ([], 0)
        assert (tmp_path / "data" / "cmrt.db").exists()
    finally:
        repo.engine.dispose()
