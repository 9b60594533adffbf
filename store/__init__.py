"""Persistence: SQLAlchemy models behind a small repository interface, Alembic migrations.

    from store import open_repository
    repo = open_repository()            # URL from CMRT_DATABASE_URL; migrates to head
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=1, workers=2)

The contract is `store.repository.Repository`, split by aggregate: `store.jobs` (jobs, driver
lease), `store.generations` (generations, evaluations), `store.library` (CMRT library, PCA
bases); `store.sql` holds what their SQLAlchemy implementations share. No web or queue imports.
"""

from __future__ import annotations

from sqlalchemy import Engine

from store.db import init_db, make_engine
from store.errors import Conflict, NotFound, StoreError
from store.records import (
    TERMINAL_STATUSES,
    CharacterRecord,
    CmrtEntry,
    CmrtKey,
    CmrtRecord,
    EvaluationRecord,
    FamilyRecord,
    FamilyScan,
    JobRecord,
    JobStart,
)
from store.repository import Repository, SqlRepository


def open_repository(url: str | None = None, *, migrate: bool = True) -> SqlRepository:
    """A SqlRepository on `url` (default: the settings' database_url), migrated to the newest
    schema unless `migrate` is False. Call once per process (after forking, not before)."""
    if url is None:
        from cmrt.settings import get_settings

        url = get_settings().database_url
        assert url is not None
    engine: Engine = init_db(url) if migrate else make_engine(url)
    return SqlRepository(engine)


__all__ = [
    "TERMINAL_STATUSES",
    "CharacterRecord",
    "CmrtEntry",
    "CmrtKey",
    "CmrtRecord",
    "Conflict",
    "EvaluationRecord",
    "FamilyRecord",
    "FamilyScan",
    "JobRecord",
    "JobStart",
    "NotFound",
    "Repository",
    "SqlRepository",
    "StoreError",
    "init_db",
    "make_engine",
    "open_repository",
]
