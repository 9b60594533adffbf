"""Celery tasks: `evaluate_candidates(job_id, generation, indices)` (what the driver sends: a
few candidates of one generation per task, see worker.executors.batch_sizes). Ids in, small dicts
out; the parameters come from, and the results go to, the
store (see worker.candidates), each candidate claimed and stored on its own, so a worker killed
mid-task loses only the candidate it was running: the re-delivered message skips the ones
already stored. After each stored result the job's driver is notified (worker.notify).

Each worker pool process opens its own repository lazily (after the fork), reads a job's spec
hash once (worker.candidates.JobSpecs) and keeps the typed spec and one simulator per spec in
the process's one spec cache (optim.objective.SPECS), so consecutive candidates of a job reuse
the ODE world and the spec is parsed once per process.

`ignore_result=True`: nothing reads a task's return value (the driver reads the store, never
`.get()`), so no result is written to the result backend. A task returns only its candidates'
statuses as one short string ("done done"), which the worker logs at INFO: Celery formats the
return value of every task (`saferepr`) and ships it from the pool process to its parent
whether or not it is logged, and a list of dicts cost ~0.3 ms per task of that.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from celery.signals import worker_process_init

from cmrt.settings import get_settings
from worker.candidates import JobSpecs, open_worker_repository, run_candidates
from worker.celery_app import TASK_EVALUATE_BATCH, app
from worker.notify import Notifier

_lock = threading.Lock()
_repo = None
_notifier: Notifier | None = None
_cache = JobSpecs()


def _repository():
    global _repo
    with _lock:
        if _repo is None:
            _repo = open_worker_repository(get_settings().database_url)
        return _repo


def _notify(job_id: str, generation: int, index: int) -> None:
    global _notifier
    if _notifier is None:
        _notifier = Notifier(get_settings().broker_url)
    _notifier.notify(job_id, generation, index)


@worker_process_init.connect
def _fresh_process(**_: Any) -> None:  # never reuse the parent's connections after fork
    global _repo, _notifier
    _repo = None
    _notifier = None


def _worker_name(task: Any) -> str:
    node = task.request.hostname or f"pid{os.getpid()}"
    return f"{node}/{os.getpid()}"


@app.task(name=TASK_EVALUATE_BATCH, bind=True, acks_late=True, reject_on_worker_lost=True,
          ignore_result=True)
def evaluate_candidates(self, job_id: str, generation: int, indices: list[int]) -> str:
    """The candidates in order, each claimed, evaluated, stored and notified on its own."""
    out = run_candidates(_repository(), job_id, int(generation), [int(i) for i in indices],
                         max_attempts=get_settings().max_attempts, cache=_cache,
                         worker_name=_worker_name(self), notify=_notify)
    return " ".join(r["status"] for r in out)
