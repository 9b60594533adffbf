"""Jobs and their driver lease: `JobRepository` (the contract) and `SqlJobs` (SQLAlchemy)."""

from __future__ import annotations

import abc
import uuid
from collections.abc import Iterable, Mapping
from datetime import timedelta
from typing import Any

from sqlalchemy import func, or_, select, update

from cmrt.canonical import document_hash
from store.db import READ_ONLY_OPTION
from store.errors import Conflict, InvalidTransition, NotFound
from store.models import BasisRow, JobRow
from store.records import (
    CANCELLED,
    JOB_STATUSES,
    QUEUED,
    RUNNING,
    TERMINAL_STATUSES,
    TRANSITIONS,
    JobRecord,
    JobStart,
)
from store.sql import (
    SqlBase,
    _job_record,
    _json,
)

#: `ping`'s statement: one id of the jobs table, if any (its primary key index alone).
_PING = select(JobRow.id).limit(1)


class JobRepository(abc.ABC):
    """Jobs (status machine of `store.records.TRANSITIONS`, cancellation) and the driver lease
    that admits one driver per job."""

    # ---- jobs ---------------------------------------------------------------------------
    @abc.abstractmethod
    def create_job(
        self,
        spec: Mapping[str, Any],
        *,
        name: str,
        family: str,
        task: str,
        seed: int | None = None,
        workers: int = 1,
        basis_id: str | None = None,
        start: JobStart | None = None,
        spec_hash: str | None = None,
    ) -> JobRecord:
        """Store a new job in status `queued` and return it (a fresh uuid4 string id).

        `spec` is the JSON form of the TaskSpec (`sim.spec.CanonicalSpec.document`) and
        `spec_hash` the hash of its canonical text (computed here when not given). `start`:
        where its search starts (None: the flat spline).
        Raises Conflict if `basis_id` names no stored basis.
        """

    @abc.abstractmethod
    def set_job_result(self, job_id: str, result: Mapping[str, Any]) -> None:
        """Keep the finished job's result document (OptimizationResult.to_dict()); NotFound."""

    @abc.abstractmethod
    def job_result(self, job_id: str) -> dict[str, Any] | None:
        """The job's result document, None before it has one; raises NotFound."""

    @abc.abstractmethod
    def get_job(self, job_id: str) -> JobRecord:
        """The job; raises NotFound."""

    @abc.abstractmethod
    def ping(self) -> None:
        """Read one row id of the jobs table (none needed): raises when the database is
        unreachable or its schema is gone. `/health`'s check, a single indexed read however
        many jobs there are (counting them grows with the table)."""

    @abc.abstractmethod
    def cancel_requested(self, job_id: str) -> bool:
        """Whether a cancel was asked for the job (its `cancel_requested` alone, without the
        rest of the row: a driver polls it twice a second); raises NotFound."""

    @abc.abstractmethod
    def cancel_flags(self, job_ids: Iterable[str]) -> dict[str, bool]:
        """Each job's `cancel_requested`, in one read (a driver process polls those of all
        its jobs at once); a job that does not exist is left out."""

    @abc.abstractmethod
    def list_jobs(
        self,
        *,
        status: str | Iterable[str] | None = None,
        family: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[JobRecord], int]:
        """One page of jobs, newest first, and the total number matching the filters."""

    @abc.abstractmethod
    def set_job_status(
        self,
        job_id: str,
        status: str,
        *,
        stop_rule: str | None = None,
        error: str | None = None,
    ) -> JobRecord:
        """Move the job to `status` along `store.records.TRANSITIONS`; return the new record.

        Sets `started_at` on entering `running` and `finished_at` on entering a terminal
        state (which also releases the driver lease); `stop_rule` and `error` are stored when
        given. Setting the status the job already has is a no-op returning the record.
        Atomic compare-and-set: of two racing changes from the same state only one wins, the
        other raises InvalidTransition. Raises NotFound, InvalidTransition, ValueError for an
        unknown status.
        """

    @abc.abstractmethod
    def request_cancel(self, job_id: str) -> JobRecord:
        """Ask for cancellation: a queued job is cancelled at once; a running job gets
        `cancel_requested` set and its driver cancels it between generations; a finished job is
        left unchanged. Returns the record. Raises NotFound."""

    # ---- driver lease -------------------------------------------------------------------
    @abc.abstractmethod
    def acquire_driver_lease(self, job_id: str, owner: str, ttl_s: float) -> bool:
        """Become the job's one driver for `ttl_s` seconds; True on success.

        Succeeds if nobody holds the lease, `owner` already holds it (then it is renewed), or
        the holder's lease has expired (takeover of a dead driver). Fails for a finished job.
        Atomic: of concurrent callers at most one succeeds. Raises NotFound.
        """

    @abc.abstractmethod
    def renew_driver_lease(self, job_id: str, owner: str, ttl_s: float) -> bool:
        """Extend `owner`'s lease (and heartbeat); False if another owner took it over."""

    @abc.abstractmethod
    def release_driver_lease(self, job_id: str, owner: str) -> None:
        """Give up the lease if `owner` holds it; otherwise do nothing."""

    @abc.abstractmethod
    def orphaned_jobs(self, limit: int = 100) -> list[JobRecord]:
        """Queued or running jobs without a live lease (never driven, or driver dead),
        oldest first: what a (re)started driver should pick up."""


class SqlJobs(SqlBase, JobRepository):
    # ---- jobs ---------------------------------------------------------------------------
    def create_job(self, spec, *, name, family, task, seed=None, workers=1, basis_id=None,
                   start=None, spec_hash=None):
        with self._write() as s:
            return self._create_job_in(s, spec, name=name, family=family, task=task, seed=seed,
                                       workers=workers, basis_id=basis_id, start=start,
                                       spec_hash=spec_hash)

    def _create_job_in(self, s, spec, *, name, family, task, seed=None, workers=1, basis_id=None,
                       start=None, spec_hash=None) -> JobRecord:
        """create_job inside the session `s` (a caller's transaction)."""
        if workers < 1:
            raise ValueError("workers must be >= 1")
        if basis_id is not None and s.get(BasisRow, basis_id) is None:
            raise Conflict(f"basis {basis_id} not found")
        doc = _json(dict(spec), "spec")
        job = JobRow(
            id=str(uuid.uuid4()), name=name, family=family, task=task, spec=doc,
            spec_hash=spec_hash or document_hash(doc), seed=seed, workers=int(workers),
            status=QUEUED,
            basis_id=basis_id, created_at=self._clock(), evaluations=0, iterations=0,
            cancel_requested=False,
            start=None if start is None else _json(start.to_json(), "start"),
        )  # fmt: skip
        s.add(job)
        s.flush()
        return _job_record(job)

    def set_job_result(self, job_id, result):
        doc = _json(dict(result), "result")
        with self._write() as s:
            res = s.execute(update(JobRow).where(JobRow.id == job_id).values(result=doc)
                            .execution_options(synchronize_session=False))
            if res.rowcount == 0:
                raise NotFound(f"job {job_id!a} not found")

    def job_result(self, job_id):
        with self._read() as s:
            row = s.execute(select(JobRow.id, JobRow.result)
                            .where(JobRow.id == job_id)).one_or_none()
            if row is None:
                raise NotFound(f"job {job_id!a} not found")
            return row[1]

    def get_job(self, job_id):
        with self._read() as s:
            job = s.get(JobRow, job_id)
            if job is None:
                raise NotFound(f"job {job_id!a} not found")
            return _job_record(job)

    def ping(self):
        # Read-only: on SQLite a plain BEGIN, never the writers' BEGIN IMMEDIATE.
        with self.engine.execution_options(**{READ_ONLY_OPTION: True}).connect() as conn:
            conn.execute(_PING).first()

    def cancel_requested(self, job_id):
        with self._read_statement() as conn:
            flag = conn.execute(
                select(JobRow.cancel_requested).where(JobRow.id == job_id)).scalar()
        if flag is None:
            raise NotFound(f"job {job_id!a} not found")
        return bool(flag)

    def cancel_flags(self, job_ids):
        ids = list(job_ids)
        if not ids:
            return {}
        with self._read_statement() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.cancel_requested).where(JobRow.id.in_(ids))).all()
        return {job_id: bool(flag) for job_id, flag in rows}

    def list_jobs(self, *, status=None, family=None, limit=50, offset=0):
        conds = []
        if status is not None:
            statuses = [status] if isinstance(status, str) else list(status)
            conds.append(JobRow.status.in_(statuses))
        if family is not None:
            conds.append(JobRow.family == family)
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(JobRow).where(*conds)) or 0
            rows = s.scalars(
                select(JobRow)
                .where(*conds)
                .order_by(JobRow.created_at.desc(), JobRow.id)
                .limit(limit)
                .offset(offset)
            ).all()
            return [_job_record(j) for j in rows], int(total)

    def set_job_status(self, job_id, status, *, stop_rule=None, error=None):
        if status not in JOB_STATUSES:
            raise ValueError(f"unknown job status {status!r}; statuses are {JOB_STATUSES}")
        sources = [src for src, dests in TRANSITIONS.items() if status in dests]
        now = self._clock()
        values: dict[str, Any] = {"status": status}
        if stop_rule is not None:
            values["stop_rule"] = stop_rule
        if error is not None:
            values["error"] = error
        if status == RUNNING:
            values["started_at"] = now
        if status in TERMINAL_STATUSES:
            values.update(finished_at=now, driver_owner=None, lease_expires_at=None)
        with self._write() as s:
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status.in_(sources))
                .values(**values)
                .execution_options(synchronize_session=False)
            )
            if res.rowcount == 0:
                current = s.scalar(select(JobRow.status).where(JobRow.id == job_id))
                if current is None:
                    raise NotFound(f"job {job_id!a} not found")
                if current != status:
                    raise InvalidTransition(job_id, current, status)
            return _job_record(s.get(JobRow, job_id, populate_existing=True))

    def request_cancel(self, job_id):
        now = self._clock()
        with self._write() as s:
            job = self._lock_job(s, job_id)
            if job.status == QUEUED:
                job.status = CANCELLED
                job.cancel_requested = True
                job.finished_at = now
                job.driver_owner = None
                job.lease_expires_at = None
            elif job.status == RUNNING:
                job.cancel_requested = True
            s.flush()
            return _job_record(job)

    # ---- driver lease -------------------------------------------------------------------
    def acquire_driver_lease(self, job_id, owner, ttl_s):
        now = self._clock()
        with self._write() as s:
            res = s.execute(
                update(JobRow)
                .where(
                    JobRow.id == job_id,
                    JobRow.status.in_([QUEUED, RUNNING]),
                    or_(
                        JobRow.driver_owner.is_(None),
                        JobRow.driver_owner == owner,
                        JobRow.lease_expires_at.is_(None),
                        JobRow.lease_expires_at < now,
                    ),
                )
                .values(
                    driver_owner=owner,
                    lease_expires_at=now + timedelta(seconds=ttl_s),
                    heartbeat_at=now,
                )
                .execution_options(synchronize_session=False)
            )
            if res.rowcount == 0:
                self._require_job(s, job_id)
                return False
            return True

    def renew_driver_lease(self, job_id, owner, ttl_s):
        now = self._clock()
        with self._write() as s:
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.driver_owner == owner)
                .values(lease_expires_at=now + timedelta(seconds=ttl_s), heartbeat_at=now)
                .execution_options(synchronize_session=False)
            )
            return res.rowcount == 1

    def release_driver_lease(self, job_id, owner):
        with self._write() as s:
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.driver_owner == owner)
                .values(driver_owner=None, lease_expires_at=None)
                .execution_options(synchronize_session=False)
            )

    def orphaned_jobs(self, limit=100):
        now = self._clock()
        with self._read() as s:
            rows = s.scalars(
                select(JobRow)
                .where(
                    JobRow.status.in_([QUEUED, RUNNING]),
                    or_(
                        JobRow.driver_owner.is_(None),
                        JobRow.lease_expires_at.is_(None),
                        JobRow.lease_expires_at < now,
                    ),
                )
                .order_by(JobRow.created_at, JobRow.id)
                .limit(limit)
            ).all()
            return [_job_record(j) for j in rows]

