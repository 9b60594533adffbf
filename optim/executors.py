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
    (`optim.rankcut`), when `fn` has `supports_cut` (takes `stop_above`). In a pool the bound
    reaches that candidate's worker through a shared array, keyed by a per-submission number
    so that no other evaluation reads it.
  * `PoolExecutor`'s worker processes never outlive the process that made the pool: each
    watches its parent and exits within PARENT_WATCH_S once the parent is gone (killed with
    SIGKILL, say, where no clean-up runs), instead of waiting on its queue for ever.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import math
import multiprocessing
import os
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from types import TracebackType
from typing import Any

import numpy as np

from optim.errors import EvaluationError
from optim.outcome import FAILED_OBJECTIVE, EvalOutcome
from optim.rankcut import bound_for_last

#: Default wall-clock limit for one batch in a process pool, seconds: far above any real batch
#: (a 20 s clip costs ~2 s of CPU; 200 of them on one worker ~400 s) so a hung worker cannot
#: block a job forever. Pass timeout=None to disable.
DEFAULT_BATCH_TIMEOUT_S: float | None = 1800.0
#: Wall-clock limit for starting the pool's worker processes (imports), seconds.
STARTUP_TIMEOUT_S = 120.0
#: Start method of pool workers: "spawn" (no forked threads or ODE state; works everywhere).
DEFAULT_START_METHOD = "spawn"
#: How often a pool worker checks that the process that made the pool is still alive, seconds.
PARENT_WATCH_S = 0.5


Objective = Callable[[np.ndarray], "EvalOutcome | float"]


def evaluate_one(fn: Objective, params: np.ndarray) -> EvalOutcome:
    """Run `fn(params)`, turning a float into an outcome and an exception into an error outcome."""
    t0 = time.process_time()
    try:
        out = fn(params)
    except Exception as err:  # noqa: BLE001 - reported per candidate, see module docstring
        return EvalOutcome(
            objective=FAILED_OBJECTIVE,
            fell=False,
            cpu_seconds=time.process_time() - t0,
            error=f"{type(err).__name__}: {err}",
        )
    if isinstance(out, EvalOutcome):
        return out
    return EvalOutcome(objective=float(out), cpu_seconds=time.process_time() - t0)


def _cut_key_bound(shared: Any, key: float) -> Callable[[], float]:
    """A `stop_above` reading the bound the parent posts for submission `key` in `shared`
    ([key, bound]; the parent writes the bound before the key): inf until it is posted."""

    def read() -> float:
        k1 = shared[0]
        b = shared[1]
        if k1 == key and shared[0] == key:
            return b
        return math.inf

    return read


#: The pool worker's shared [key, bound] array (set by the initializer), None elsewhere.
_CUT_SHARED: Any = None


def evaluate_one_cuttable(fn: Objective, params: np.ndarray, key: float) -> EvalOutcome:
    """`evaluate_one` in a pool worker, `fn` stopping early once the parent posts a bound
    for `key` that its objective's lower bound exceeds (see module docstring)."""
    shared = _CUT_SHARED
    if shared is None:
        return evaluate_one(fn, params)
    reader = _cut_key_bound(shared, key)
    return evaluate_one(lambda x: fn(x, stop_above=reader), params)


def _init_pool_worker(parent_pid: int, shared: Any) -> None:
    """Pool-worker initializer: the parent watch, and the shared cut array."""
    global _CUT_SHARED
    _CUT_SHARED = shared
    _exit_with_parent(parent_pid)


def _ping() -> int:
    return os.getpid()


def _exit_with_parent(parent_pid: int) -> None:
    """Pool-worker initializer: a daemon thread ends this process once its parent is gone.

    Without it a worker whose parent was killed waits on the call queue for ever (every
    worker holds the queue's write end too, so no end-of-file ever comes)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_WATCH_S)
        os._exit(1)  # no clean-up to run: the parent that wanted the results is gone

    threading.Thread(target=watch, name="cmrt-parent-watch", daemon=True).start()


def kill_process_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Kill a process pool's worker processes (SIGKILL) and shut it down without waiting."""
    procs = list(getattr(pool, "_processes", {}).values())  # private, but the only handle
    for p in procs:
        with contextlib.suppress(Exception):
            p.kill()
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5.0)


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
        if cut_margin is None or len(xs) < 2 or not getattr(fn, "supports_cut", False):
            return [evaluate_one(fn, x) for x in xs]
        out = [evaluate_one(fn, x) for x in xs[:-1]]
        bound = bound_for_last([o.objective for o in out], cut_margin)
        out.append(evaluate_one(lambda x: fn(x, stop_above=lambda: bound), xs[-1]))
        return out


class PoolExecutor(Executor):
    """A `concurrent.futures.ProcessPoolExecutor` of `workers` processes, reused across batches.

    timeout: wall-clock seconds allowed for one whole batch (None: no limit). A timeout or a
    dead worker raises `EvaluationError`; see module docstring.
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
        self._ctx = multiprocessing.get_context(start_method)
        self._pool: cf.ProcessPoolExecutor | None = None
        self._closed = False
        self._cut_shared: Any = None  # [key, bound] shared with the workers
        self._cut_key = 0.0
        # Several threads may share the pool (optim.family_run): it is made once.
        self._start_lock = threading.Lock()

    @property
    def workers(self) -> int:
        return self._workers

    def _get_pool(self) -> cf.ProcessPoolExecutor:
        with self._start_lock:
            return self._get_pool_locked()

    def _get_pool_locked(self) -> cf.ProcessPoolExecutor:
        if self._closed:
            raise EvaluationError("PoolExecutor is closed")
        if self._pool is None:
            self._cut_shared = self._ctx.RawArray("d", [-1.0, math.inf])
            self._pool = cf.ProcessPoolExecutor(max_workers=self._workers, mp_context=self._ctx,
                                                initializer=_init_pool_worker,
                                                initargs=(os.getpid(), self._cut_shared))
            self._warm_up()
        return self._pool

    def _warm_up(self) -> None:
        """Start the workers (imports) before any batch timer runs (STARTUP_TIMEOUT_S)."""
        assert self._pool is not None
        futures = [self._pool.submit(_ping) for _ in range(self._workers)]
        done, not_done = cf.wait(futures, timeout=STARTUP_TIMEOUT_S)
        try:
            if not_done:
                raise EvaluationError(
                    f"worker processes did not start within {STARTUP_TIMEOUT_S:g} s"
                )
            for fut in done:
                fut.result()
        except BrokenProcessPool:
            self._kill_pool()
            raise EvaluationError("a worker process died while starting") from None
        except EvaluationError:
            self._kill_pool()
            raise

    def _kill_pool(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            kill_process_pool(pool)

    def _submit(self, pool: cf.ProcessPoolExecutor, fn: Objective, batch: Sequence[np.ndarray],
                cut: bool) -> tuple[list[cf.Future], list[float]]:
        if not cut:
            return [pool.submit(evaluate_one, fn, np.asarray(x, dtype=float)) for x in batch], []
        keys = []
        futures = []
        for x in batch:
            self._cut_key += 1.0
            keys.append(self._cut_key)
            futures.append(pool.submit(evaluate_one_cuttable, fn, np.asarray(x, dtype=float),
                                       self._cut_key))
        return futures, keys

    def _wait_cutting(self, futures: list[cf.Future], keys: list[float],
                      margin: float) -> set[cf.Future]:
        """Wait for the batch; once one future is left, post its bound (the others' values)."""
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        pending = set(futures)
        posted = False
        while pending:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            done, pending = cf.wait(pending, timeout=left, return_when=cf.FIRST_COMPLETED)
            if not done:
                return pending  # timed out
            if len(pending) == 1 and not posted:
                posted = True
                last = next(iter(pending))
                try:
                    vals = [f.result().objective for f in futures if f is not last]
                except Exception:  # noqa: BLE001 - reported by map's result loop
                    continue
                shared = self._cut_shared
                shared[1] = bound_for_last(vals, margin)
                shared[0] = keys[futures.index(last)]  # the key last: see _cut_key_bound
        return pending

    def map(self, fn: Objective, batch: Sequence[np.ndarray],
            cut_margin: float | None = None) -> list[EvalOutcome]:
        if len(batch) == 0:
            return []
        pool = self._get_pool()
        cut = cut_margin is not None and len(batch) >= 2 and getattr(fn, "supports_cut", False)
        try:
            futures, keys = self._submit(pool, fn, batch, cut)
        except BrokenProcessPool as err:
            self._kill_pool()
            raise EvaluationError(
                f"a worker process died before the batch started: {err}"
            ) from None
        if cut:
            assert cut_margin is not None
            not_done = self._wait_cutting(futures, keys, cut_margin)
        else:
            _done, not_done = cf.wait(futures, timeout=self._timeout)
        if not_done:
            self._kill_pool()
            raise EvaluationError(
                f"batch of {len(batch)} candidates timed out after {self._timeout:g} s "
                f"({len(not_done)} unfinished); the worker pool was restarted"
            )
        out: list[EvalOutcome] = []
        for i, fut in enumerate(futures):
            try:
                out.append(fut.result())
            except BrokenProcessPool:
                self._kill_pool()
                raise EvaluationError(
                    f"a worker process died while evaluating candidate {i} of {len(batch)} "
                    "(crash, out of memory or killed); the worker pool was restarted"
                ) from None
            except Exception as err:  # noqa: BLE001 - e.g. fn not picklable
                self._kill_pool()
                raise EvaluationError(
                    f"candidate {i} could not be evaluated in a worker process: "
                    f"{type(err).__name__}: {err}"
                ) from err
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._closed = True


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
