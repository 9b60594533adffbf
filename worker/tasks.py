"""Celery tasks. `evaluate_candidate(job_id, generation, index)`: ids in, a small dict out;
the parameters come from, and the result goes to, the store (see worker.evaluation).

Each worker pool process opens its own repository lazily (after the fork) and keeps one
simulator per job (worker.evaluation.SpecCache), so consecutive candidates of a job reuse the
ODE world.

`ignore_result=True`: nothing reads a task's return value (the driver polls the store, never
`.get()`), so no result is written to the result backend; the small dict returned is only
logged by the worker.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from celery.signals import worker_process_init

from cmrt.settings import get_settings
from worker.celery_app import TASK_EVALUATE, app
from worker.evaluation import SpecCache, open_worker_repository, run_candidate

_lock = threading.Lock()
_repo = None
_cache = SpecCache()


def _repository():
    global _repo
    with _lock:
        if _repo is None:
            _repo = open_worker_repository(get_settings().database_url)
        return _repo


@worker_process_init.connect
def _fresh_process(**_: Any) -> None:  # never reuse the parent's connections after fork
    global _repo
    _repo = None


@app.task(name=TASK_EVALUATE, bind=True, acks_late=True, reject_on_worker_lost=True,
          ignore_result=True)
def evaluate_candidate(self, job_id: str, generation: int, index: int) -> dict[str, Any]:
    node = getattr(self.request, "hostname", None) or f"pid{os.getpid()}"
    return run_candidate(
        _repository(),
        job_id,
        int(generation),
        int(index),
        max_attempts=get_settings().max_attempts,
        cache=_cache,
        worker_name=f"{node}/{os.getpid()}",
    )
