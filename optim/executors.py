"""Evaluate a batch of candidates: in this process, or in a local process pool.

Contracts:
  * `Executor.map(fn, batch)` returns one `EvalOutcome` per candidate, in batch order.
    `fn(params) -> EvalOutcome | float` must be deterministic and, for `PoolExecutor`,
    picklable (a top-level function or an instance of a top-level class such as
    `optim.objective.SimObjective`). A plain float return is wrapped into an outcome.
  * An exception raised by `fn` for one candidate does not fail the batch: that candidate's
    outcome has `error` set (type and message), `objective = FAILED_OBJECTIVE`, `fell = False`.
    Both executors do this identically, so the same seed gives the same optimisation whether
    candidates are evaluated serially or by any number of workers.
  * `PoolExecutor` raises `EvaluationError` (never hangs) when a worker process dies
    (BrokenProcessPool) or a batch exceeds its timeout; the broken pool is torn down (its
    processes killed) and a fresh one is started by the next `map`.
  * `map(fn, batch, cut_margin=m)` (m from `optim.rankcut.cut_margin`; None: no cut) lets the
    last unfinished candidate of the batch stop early once it certainly ranks last
    (`optim.rankcut`), when `fn` is an `optim.outcome.CuttableObjective` (takes `stop_above`).
  * `PoolExecutor` is the one process pool (`optim.procpool.SlotPool`): its processes never
    outlive the process that made it (each watches it and exits within PARENT_WATCH_S once it
    is gone, killed with SIGKILL, say, where no clean-up runs).
"""

from __future__ import annotations

import os
import threading
from abc import ABC, abstractmethod
from collections.abc import Sequence
from types import TracebackType
from typing import Any

import numpy as np

from optim.errors import EvaluationError
from optim.outcome import FAILED_OBJECTIVE, CuttableObjective, EvalOutcome, Objective
from optim.procpool import (
    PARENT_WATCH_S,
    SlotPool,
    WorkerDiedError,
    evaluate_one,
    kill_process_pool,
)
from optim.rankcut import bound_for_last

#: Default wall-clock limit for one batch in a process pool, seconds: far above any real batch
#: (a 20 s clip costs ~2 s of CPU; 200 of them on one worker ~400 s) so a hung worker cannot
#: block a job forever. Pass timeout=None to disable.
DEFAULT_BATCH_TIMEOUT_S: float | None = 1800.0
#: Wall-clock limit for starting the pool's worker processes (imports), seconds.
STARTUP_TIMEOUT_S = 120.0
#: Start method of pool workers: "spawn" (no forked threads or ODE state; works everywhere).
DEFAULT_START_METHOD = "spawn"


class Executor(ABC):
    """Evaluates batches of candidates; a context manager (`close()` on exit)."""

    @abstractmethod
    def map(self, fn: Objective, batch: Sequence[np.ndarray],
            cut_margin: float | None = None) -> list[EvalOutcome]:
        """One outcome per candidate, in order (see module docstring)."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release workers; the executor must not be used afterwards."""

    @property
    def workers(self) -> int:
        return 1

    def __enter__(self) -> Executor:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class SerialExecutor(Executor):
    """Evaluates candidates one after the other in the calling process."""

    def map(self, fn: Objective, batch: Sequence[np.ndarray],
            cut_margin: float | None = None) -> list[EvalOutcome]:
        xs = [np.asarray(x, dtype=float) for x in batch]
        if cut_margin is None or len(xs) < 2 or not isinstance(fn, CuttableObjective):
            return [evaluate_one(fn, x) for x in xs]
        out = [evaluate_one(fn, x) for x in xs[:-1]]
        bound = bound_for_last([o.objective for o in out], cut_margin)
        out.append(evaluate_one(lambda x: fn(x, stop_above=lambda: bound), xs[-1]))
        return out


class PoolExecutor(Executor):
    """`workers` processes of the one process pool (`optim.procpool.SlotPool`), reused across
    batches; several threads may share it (`optim.family_run`), each `map` a group of its own.

    timeout: wall-clock seconds allowed for one whole batch (None: no limit). A timeout or a
    dead worker raises `EvaluationError` (never hangs): the batch's running processes are
    killed and restarted, its queued candidates dropped.
    """

    def __init__(
        self,
        workers: int | None = None,
        *,
        timeout: float | None = DEFAULT_BATCH_TIMEOUT_S,
        start_method: str = DEFAULT_START_METHOD,
    ) -> None:
        n = workers if workers is not None else (os.cpu_count() or 1)
        if n < 1:
            raise ValueError(f"PoolExecutor needs at least 1 worker, got {n}")
        if timeout is not None and timeout <= 0:
            raise ValueError("PoolExecutor timeout must be positive seconds or None")
        self._workers = int(n)
        self._timeout = timeout
        self._pool = SlotPool(self._workers, start_method=start_method)
        self._warm = False
        self._batches = 0
        # Several threads may share the pool (optim.family_run): it is warmed up once.
        self._start_lock = threading.Lock()

    @property
    def workers(self) -> int:
        return self._workers

    def pids(self) -> list[int]:
        """The worker processes' ids (after the first batch)."""
        return self._pool.pids()

    def _warm_up(self) -> int:
        """Start the workers (imports) before any batch timer runs (STARTUP_TIMEOUT_S); returns
        a new batch number (the batch's group in the pool)."""
        with self._start_lock:
            if self._pool.closed:
                raise EvaluationError("PoolExecutor is closed")
            if not self._warm:
                self._pool.warm_up(STARTUP_TIMEOUT_S)
                self._warm = True
            self._batches += 1
            return self._batches

    def map(self, fn: Objective, batch: Sequence[np.ndarray],
            cut_margin: float | None = None) -> list[EvalOutcome]:
        if len(batch) == 0:
            return []
        group = self._warm_up()
        out: list[Any] = [None] * len(batch)

        def on_result(i: int, o: EvalOutcome | EvaluationError) -> None:
            out[i] = o

        if not self._pool.run(group, fn, batch, on_result, timeout=self._timeout,
                              cut_margin=cut_margin):
            unfinished = sum(o is None for o in out)
            raise EvaluationError(
                f"batch of {len(batch)} candidates timed out after {self._timeout:g} s "
                f"({unfinished} unfinished); their worker processes were restarted"
            )
        for i, o in enumerate(out):
            if isinstance(o, WorkerDiedError):
                raise EvaluationError(
                    f"a worker process died while evaluating candidate {i} of {len(batch)} "
                    "(crash, out of memory or killed); it was restarted"
                )
            if isinstance(o, BaseException):  # e.g. fn not picklable
                raise EvaluationError(
                    f"candidate {i} could not be evaluated in a worker process: "
                    f"{type(o).__name__}: {o}"
                ) from o
        return out

    def close(self) -> None:
        self._pool.close()


def make_executor(workers: int | None = 1, **kwargs: Any) -> Executor:
    """SerialExecutor for workers == 1, else PoolExecutor(workers, **kwargs)."""
    if workers == 1:
        return SerialExecutor()
    return PoolExecutor(workers, **kwargs)


__all__ = [
    "DEFAULT_BATCH_TIMEOUT_S",
    "FAILED_OBJECTIVE",
    "PARENT_WATCH_S",
    "STARTUP_TIMEOUT_S",
    "EvalOutcome",
    "Executor",
    "PoolExecutor",
    "SerialExecutor",
    "evaluate_one",
    "kill_process_pool",
    "make_executor",
]
