"""Reads the tests need that the service does not (so they are not part of the Repository):
straight SQL on the repository's engine, returning the store's records."""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session, undefer

from store.errors import NotFound
from store.models import BasisRow, CmrtRow, EvaluationRow, JobRow
from store.records import BasisRecord, EvaluationRecord
from store.sql import row_record


def get_evaluation(repo, job_id: str, generation: int, index: int) -> EvaluationRecord:
    """One evaluation; raises NotFound."""
    with Session(repo.engine) as s:
        ev = s.scalars(select(EvaluationRow).where(
            EvaluationRow.job_id == job_id, EvaluationRow.generation == generation,
            EvaluationRow.index == index)).one_or_none()
        if ev is None:
            raise NotFound(f"evaluation ({job_id}, {generation}, {index}) not found")
        return row_record(EvaluationRecord, ev)


def get_optimizer_state(repo, job_id: str) -> bytes | None:
    """The job's pickled optimizer of its newest generation; raises NotFound."""
    with Session(repo.engine) as s:
        job = s.scalars(select(JobRow).options(undefer(JobRow.optimizer_state))
                        .where(JobRow.id == job_id)).one_or_none()
        if job is None:
            raise NotFound(f"job {job_id} not found")
        return job.optimizer_state


def cmrt_families(repo) -> dict[str, int]:
    """Family name -> number of library CMRTs."""
    with Session(repo.engine) as s:
        rows = s.execute(select(CmrtRow.family, func.count()).group_by(CmrtRow.family)
                         .order_by(CmrtRow.family)).all()
        return {f: int(n) for f, n in rows}


def list_bases(repo, family: str | None = None) -> list[BasisRecord]:
    """Bases (of one family if given), newest first."""
    conds = [] if family is None else [BasisRow.family == family]
    with Session(repo.engine) as s:
        rows = s.scalars(select(BasisRow).where(*conds)
                         .order_by(BasisRow.created_at.desc(), BasisRow.id)).all()
        return [row_record(BasisRecord, b) for b in rows]
