"""Domain errors of the store. Callers never see SQLAlchemy exceptions for these cases."""

from __future__ import annotations


class StoreError(Exception):
    """Base class of every error raised by the store."""


class NotFound(StoreError):  # noqa: N818 (names fixed by the contract)
    """The job, generation, evaluation, CMRT or basis does not exist."""


class InvalidTransition(StoreError):  # noqa: N818
    """A job status change that the state machine does not allow.

    Attributes: `job_id`, `current` (status now), `requested` (status asked for).
    """

    def __init__(self, job_id: str, current: str, requested: str) -> None:
        super().__init__(f"job {job_id}: cannot go from {current!r} to {requested!r}")
        self.job_id = job_id
        self.current = current
        self.requested = requested


class Conflict(StoreError):  # noqa: N818
    """A write that contradicts stored data (e.g. a reference to a missing job or basis)."""
