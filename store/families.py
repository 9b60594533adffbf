"""Families of CMRTs: `FamilyRepository` (the contract) and `SqlFamilies` (SQLAlchemy).

A family stores its request (the FamilySpec's JSON form), its status, the probes' outcomes and
its report; each run of its plan is an ordinary job, linked by `(family, run id)`, created at
most once (`add_family_run` is idempotent) so that several drivers may advance one family.
"""

from __future__ import annotations

import abc
import uuid
from collections.abc import Collection, Mapping, Sequence
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError

from cmrt.canonical import document_hash
from store.errors import NotFound
from store.models import FamilyRow, FamilyRunRow, JobRow
from store.records import (
    FAMILY_RUNNING,
    FAMILY_TERMINAL,
    FamilyRecord,
    FamilyScan,
    JobRecord,
    JobStart,
)
from store.sql import SqlBase, _job_record, _json, row_record


class FamilyRepository(abc.ABC):
    """Families: the request, the runs' jobs, the probes and the report."""

    @abc.abstractmethod
    def create_family(self, spec: Mapping[str, Any], *, family: str, param: str,
                      spec_hash: str | None = None) -> FamilyRecord:
        """Store a new family (status `running`) and return it; `spec_hash`: the hash of the
        request's canonical text (cmrt.canonical; computed here when not given)."""

    @abc.abstractmethod
    def get_family(self, family_id: str) -> FamilyRecord:
        """The family with its runs' job ids; raises NotFound."""

    @abc.abstractmethod
    def list_families(
        self, *, status: str | None = None, limit: int = 50, offset: int = 0
    ) -> tuple[list[FamilyRecord], int]:
        """Families (of one status if given), newest first, and their total count."""

    @abc.abstractmethod
    def active_families(self, limit: int = 100) -> list[FamilyRecord]:
        """Families not finished yet, oldest first: what a driver advances."""

    @abc.abstractmethod
    def add_family_run(self, family_id: str, run_id: str, spec: Mapping[str, Any], *,
                       name: str, family: str, task: str, seed: int | None = None,
                       basis_id: str | None = None, start: JobStart | None = None,
                       spec_hash: str | None = None) -> JobRecord:
        """The job of run `run_id`: created as `create_job` would (the same arguments) unless
        the run has one already, in which case that one is returned (idempotent). Creating
        the job and linking it is one transaction."""

    @abc.abstractmethod
    def family_jobs(self, family_id: str) -> dict[str, JobRecord]:
        """run id -> the job of every run started so far; raises NotFound."""

    @abc.abstractmethod
    def family_scan(self, family_id: str, known: Collection[str] = ()) -> FamilyScan:
        """The family, its runs' jobs, the result documents of its finished runs but those
        in `known` (the ones the caller has), and its probes: one transaction, what a
        family driver reads at a step. Raises NotFound."""

    @abc.abstractmethod
    def set_family_probes(self, family_id: str, probes: Any) -> None:
        """Keep the probes' outcomes (JSON data)."""

    @abc.abstractmethod
    def family_probes(self, family_id: str) -> Any | None:
        """The probes' outcomes, None before they are evaluated."""

    @abc.abstractmethod
    def finish_family(self, family_id: str, status: str, *, report: Any = None,
                      error: str | None = None) -> FamilyRecord:
        """Set a terminal status (done with its report, failed with the reason, cancelled);
        a family already terminal keeps its status. Returns the family."""

    @abc.abstractmethod
    def family_report(self, family_id: str) -> Any | None:
        """The finished family's report, None before it has one; raises NotFound."""

    @abc.abstractmethod
    def request_family_cancel(self, family_id: str) -> FamilyRecord:
        """Flag the family for cancellation (its driver cancels its running jobs and ends it
        `cancelled`); a terminal family is left alone. Raises NotFound."""


def _family_record(f: FamilyRow, runs: dict[str, str]) -> FamilyRecord:
    return row_record(FamilyRecord, f, cancel_requested=bool(f.cancel_requested), runs=runs)


class SqlFamilies(SqlBase, FamilyRepository):
    def _runs(self, s: Any, family_ids: Sequence[str]) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {fid: {} for fid in family_ids}
        if family_ids:
            for fid, rid, jid in s.execute(
                select(FamilyRunRow.family_id, FamilyRunRow.run_id, FamilyRunRow.job_id)
                .where(FamilyRunRow.family_id.in_(list(family_ids)))
            ):
                out[fid][rid] = jid
        return out

    def create_family(self, spec, *, family, param, spec_hash=None):
        doc = _json(dict(spec), "spec")
        row = FamilyRow(id=str(uuid.uuid4()), family=family, param=param, spec=doc,
                     spec_hash=spec_hash or document_hash(doc), status=FAMILY_RUNNING, error=None,
                     cancel_requested=False, created_at=self._clock())
        with self._write() as s:
            s.add(row)
            s.flush()
            return _family_record(row, {})

    def get_family(self, family_id):
        with self._read() as s:
            row = s.get(FamilyRow, family_id)
            if row is None:
                raise NotFound(f"family {family_id!a} not found")
            return _family_record(row, self._runs(s, [family_id])[family_id])

    def list_families(self, *, status=None, limit=50, offset=0):
        conds = [] if status is None else [FamilyRow.status == status]
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(FamilyRow).where(*conds)) or 0
            rows = s.scalars(select(FamilyRow).where(*conds)
                             .order_by(FamilyRow.created_at.desc(), FamilyRow.id)
                             .limit(limit).offset(offset)).all()
            runs = self._runs(s, [r.id for r in rows])
            return [_family_record(r, runs[r.id]) for r in rows], int(total)

    def active_families(self, limit=100):
        with self._read() as s:
            rows = s.scalars(select(FamilyRow).where(FamilyRow.status.not_in(FAMILY_TERMINAL))
                             .order_by(FamilyRow.created_at, FamilyRow.id).limit(limit)).all()
            runs = self._runs(s, [r.id for r in rows])
            return [_family_record(r, runs[r.id]) for r in rows]

    def add_family_run(self, family_id, run_id, spec, **job):
        existing = self._run_job(family_id, run_id)
        if existing is not None:
            return existing
        try:
            with self._write() as s:
                if s.get(FamilyRow, family_id) is None:
                    raise NotFound(f"family {family_id!a} not found")
                rec = self._create_job_in(s, spec, **job)
                s.add(FamilyRunRow(family_id=family_id, run_id=run_id, job_id=rec.id))
                s.flush()
                return rec
        except IntegrityError:  # another driver created it first: that one is the run's job
            existing = self._run_job(family_id, run_id)
            if existing is None:
                raise
            return existing

    def _run_job(self, family_id: str, run_id: str) -> JobRecord | None:
        with self._read() as s:
            job = s.scalars(
                select(JobRow).join(FamilyRunRow, FamilyRunRow.job_id == JobRow.id).where(
                    FamilyRunRow.family_id == family_id, FamilyRunRow.run_id == run_id)
            ).one_or_none()
            return None if job is None else _job_record(job)

    def family_jobs(self, family_id):
        with self._read() as s:
            if s.get(FamilyRow, family_id) is None:
                raise NotFound(f"family {family_id!a} not found")
            rows = s.execute(select(FamilyRunRow.run_id, JobRow)
                             .join(JobRow, FamilyRunRow.job_id == JobRow.id)
                             .where(FamilyRunRow.family_id == family_id)).all()
            return {rid: _job_record(job) for rid, job in rows}

    def family_scan(self, family_id, known=()):
        with self._read() as s:
            fam = s.execute(select(FamilyRow, FamilyRow.probes).where(FamilyRow.id == family_id)
                            ).one_or_none()
            if fam is None:
                raise NotFound(f"family {family_id!a} not found")
            jobs = {rid: _job_record(job) for rid, job in s.execute(
                select(FamilyRunRow.run_id, JobRow).join(JobRow, FamilyRunRow.job_id == JobRow.id)
                .where(FamilyRunRow.family_id == family_id))}
            want = [rid for rid, j in jobs.items() if j.terminal and rid not in known]
            results = {} if not want else {rid: res for rid, res in s.execute(
                select(FamilyRunRow.run_id, JobRow.result)
                .join(JobRow, FamilyRunRow.job_id == JobRow.id)
                .where(FamilyRunRow.family_id == family_id, FamilyRunRow.run_id.in_(want)))
                if res is not None}
            record = _family_record(fam[0], {rid: j.id for rid, j in jobs.items()})
            return FamilyScan(record, jobs, results, fam[1])

    def set_family_probes(self, family_id, probes):
        doc = _json(probes, "probes")
        with self._write() as s:
            if s.execute(update(FamilyRow).where(FamilyRow.id == family_id).values(probes=doc)
                         .execution_options(synchronize_session=False)).rowcount == 0:
                raise NotFound(f"family {family_id!a} not found")

    def family_probes(self, family_id):
        with self._read() as s:
            return s.scalar(select(FamilyRow.probes).where(FamilyRow.id == family_id))

    def finish_family(self, family_id, status, *, report=None, error=None):
        if status not in FAMILY_TERMINAL:
            raise ValueError(f"finish_family: {status!r} is not one of {sorted(FAMILY_TERMINAL)}")
        values: dict[str, Any] = {"status": status, "finished_at": self._clock()}
        if report is not None:
            values["report"] = _json(report, "report")
        if error is not None:
            values["error"] = error
        with self._write() as s:
            s.execute(update(FamilyRow).where(FamilyRow.id == family_id,
                                           FamilyRow.status.not_in(FAMILY_TERMINAL))
                      .values(**values).execution_options(synchronize_session=False))
        return self.get_family(family_id)

    def family_report(self, family_id):
        with self._read() as s:
            row = s.execute(select(FamilyRow.id, FamilyRow.report).where(FamilyRow.id == family_id)
                            ).one_or_none()
            if row is None:
                raise NotFound(f"family {family_id!a} not found")
            return row[1]

    def request_family_cancel(self, family_id):
        with self._write() as s:
            s.execute(update(FamilyRow).where(FamilyRow.id == family_id,
                                           FamilyRow.status.not_in(FAMILY_TERMINAL))
                      .values(cancel_requested=True)
                      .execution_options(synchronize_session=False))
        return self.get_family(family_id)


__all__ = ["FamilyRepository", "SqlFamilies"]
