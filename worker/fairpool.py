"""The embedded default's evaluation processes: a pool shared fairly by jobs, whose running
candidates can be dropped.

`FairPool(workers)` keeps `workers` single-process slots (each its own one-process
`concurrent.futures.ProcessPoolExecutor`, so one slot can be killed without touching the
others). `run(job, fn, batch, check, on_result)` queues the job's candidates; whenever a slot is
free the next candidate is taken round-robin over the jobs that have some queued, so a small
job sent after a huge one starts as soon as one running candidate ends (a job not served yet
goes first), never after the huge job's whole generation.

Contracts:
  * `on_result(i, outcome)` is called in the caller's thread as each candidate finishes, in
    completion order, with an `EvalOutcome` or an `EvaluationError` (its process died: crash,
    out of memory, killed; or it ran past `time_limit` and was killed). An exception inside
    `fn` is an outcome with `error` set (`optim.executors.evaluate_one`), as everywhere.
  * `check()` is called at least every `POLL_S` while waiting; if it raises, the job's queued
    candidates are removed, the slots running its candidates are killed (their processes
    restart on next use) and the exception propagates: a cancelled or stopped job costs no more
    CPU within a poll.
  * Slot processes ignore SIGINT and SIGTERM (a signal to the whole process group, Ctrl-C or
    `kill -- -PGID`, stops the parent, which ends its slots; it never looks like a crash) and
    exit by themselves within PARENT_WATCH_S once the server process is gone (killed with
    SIGKILL, say); the fork server then exits too.
"""

from __future__ import annotations

import concurrent.futures as cf
import itertools
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from optim.errors import EvaluationError
from optim.executors import PARENT_WATCH_S, evaluate_one, kill_process_pool
from optim.outcome import EvalOutcome

log = logging.getLogger(__name__)

#: Longest wait between two `check()` calls while a batch runs, seconds.
POLL_S = 0.1
#: Start method of the slot processes: a fork server (started like "spawn", so no thread or
#: ODE state of the server is inherited) that has imported `FORKSERVER_PRELOAD`.
DEFAULT_SLOT_START_METHOD = "forkserver"
FORKSERVER_PRELOAD = ("numpy", "optim.objective", "optim.spline", "sim.rollout", "worker.fairpool",
                      "worker.slotwarm")

OnResult = Callable[[int, "EvalOutcome | EvaluationError"], None]


def _ping() -> int:
    return os.getpid()


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except FileNotFoundError:
        return False
    except OSError:  # no /proc: fall back to a signal 0
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True


def _slot_init(server_pid: int) -> None:
    """Slot-process initializer: ignore group signals; exit once the server is gone (the
    slot's parent is the fork server, which outlives a server killed with SIGKILL while its
    slots live, so the watch is on the server itself)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)

    def watch() -> None:
        while _alive(server_pid):
            time.sleep(PARENT_WATCH_S)
        os._exit(1)  # nobody is left to want the result

    threading.Thread(target=watch, name="cmrt-server-watch", daemon=True).start()


@dataclass(eq=False)
class _Task:
    job: str
    index: int
    fn: Any
    params: np.ndarray
    done: cf.Future = field(default_factory=cf.Future)
    started: float | None = None
    dropped: bool = False


class _Slot:
    def __init__(self, number: int, ctx: Any) -> None:
        self.number, self._ctx = number, ctx
        self.executor: cf.ProcessPoolExecutor | None = None
        self.task: _Task | None = None

    def submit(self, task: _Task) -> cf.Future:
        if self.executor is None:
            self._start()
        self.task = task
        task.started = time.monotonic()
        return self.executor.submit(evaluate_one, task.fn, task.params)

    def _start(self) -> None:
        self.executor = cf.ProcessPoolExecutor(max_workers=1, mp_context=self._ctx,
                                               initializer=_slot_init, initargs=(os.getpid(),))

    def kill(self, *, restart: bool = False) -> None:
        """Kill the slot's process; with `restart` start its successor at once (its imports
        then overlap the wait for the next candidate)."""
        ex, self.executor, self.task = self.executor, None, None
        if restart:
            self._start()
            self.executor.submit(_ping)
        if ex is not None:
            kill_process_pool(ex)


class FairPool:
    """See the module docstring. Thread-safe: several job drivers share one pool."""

    def __init__(self, workers: int, *, time_limit: float | None = None,
                 start_method: str = DEFAULT_SLOT_START_METHOD) -> None:
        if workers < 1:
            raise ValueError(f"FairPool needs at least 1 worker, got {workers}")
        ctx = multiprocessing.get_context(start_method)
        if start_method == "forkserver":
            # the fork server imports the simulation once; a killed slot's successor is a
            # fork of it (milliseconds) instead of a fresh interpreter importing everything
            ctx.set_forkserver_preload(list(FORKSERVER_PRELOAD))
        self._slots = [_Slot(i, ctx) for i in range(int(workers))]
        self._queues: OrderedDict[str, deque[_Task]] = OrderedDict()
        self._lock = threading.RLock()
        self._time_limit = time_limit
        self._closed = False
        self._seq = itertools.count()
        #: Candidates started, per job (for tests and /health).
        self.started: dict[str, int] = {}

    @property
    def workers(self) -> int:
        return len(self._slots)

    # -- scheduling (under the lock) -------------------------------------------------------------
    def _next_task(self) -> _Task | None:
        for job in list(self._queues):
            q = self._queues[job]
            if q:
                task = q.popleft()
                self._queues.move_to_end(job)  # round robin: this job goes to the back
                return task
            del self._queues[job]
        return None

    def _dispatch(self) -> None:
        with self._lock:
            if self._closed:
                return
            for slot in self._slots:
                if slot.task is not None:
                    continue
                task = self._next_task()
                if task is None:
                    return
                self.started[task.job] = self.started.get(task.job, 0) + 1
                try:
                    fut = slot.submit(task)
                except BrokenProcessPool:
                    slot.kill()
                    task.done.set_exception(EvaluationError(
                        f"the worker process of slot {slot.number} died before the candidate "
                        "started"))
                    continue
                fut.add_done_callback(lambda f, s=slot, t=task: self._finished(s, t, f))

    def _finished(self, slot: _Slot, task: _Task, fut: cf.Future) -> None:
        with self._lock:
            if slot.task is task:
                slot.task = None
            if task.dropped or task.done.done():
                pass
            else:
                try:
                    task.done.set_result(fut.result())
                except BrokenProcessPool:
                    slot.kill()
                    task.done.set_exception(EvaluationError(
                        f"the worker process evaluating candidate {task.index} died (crash, "
                        "out of memory or killed)"))
                except cf.CancelledError:
                    task.done.set_exception(EvaluationError(
                        f"candidate {task.index} was cancelled inside the pool"))
                except Exception as err:  # noqa: BLE001 - e.g. fn not picklable
                    task.done.set_exception(EvaluationError(
                        f"candidate {task.index} could not be evaluated in a worker process: "
                        f"{type(err).__name__}: {err}"))
        self._dispatch()

    def _drop(self, job: str, tasks: Sequence[_Task]) -> int:
        """Remove the job's queued tasks and kill the slots running its tasks; returns how
        many were running."""
        killed = 0
        with self._lock:
            self._queues.pop(job, None)
            for t in tasks:
                t.dropped = True
            for slot in self._slots:
                if slot.task is not None and slot.task.job == job and slot.task in tasks:
                    slot.kill(restart=not self._closed)
                    killed += 1
        self._dispatch()
        return killed

    def _overdue(self, tasks: Sequence[_Task]) -> None:
        if self._time_limit is None:
            return
        now = time.monotonic()
        with self._lock:
            for slot in self._slots:
                t = slot.task
                if t is not None and t in tasks and t.started is not None \
                        and now - t.started > self._time_limit:
                    slot.kill()
                    t.done.set_exception(EvaluationError(
                        f"candidate {t.index} ran past the time limit of {self._time_limit:g} s "
                        "(CMRT_EVAL_TIME_LIMIT) and its worker process was killed"))
        self._dispatch()

    # -- the caller's side -----------------------------------------------------------------------
    def run(self, job: str, fn: Any, batch: Sequence[np.ndarray], check: Callable[[], None],
            on_result: OnResult) -> None:
        """Evaluate `batch` for `job` (see the module docstring)."""
        if self._closed:
            raise EvaluationError("the evaluation pool is closed")
        tasks = [_Task(job, i, fn, np.asarray(x, dtype=float)) for i, x in enumerate(batch)]
        with self._lock:
            if job not in self._queues:  # a job not served yet goes first
                self._queues[job] = deque()
                self._queues.move_to_end(job, last=False)
            self._queues[job].extend(tasks)
        self._dispatch()
        waiting = {t.done: t for t in tasks}
        try:
            while waiting:
                done, _ = cf.wait(list(waiting), timeout=POLL_S,
                                  return_when=cf.FIRST_COMPLETED)
                for fut in done:
                    t = waiting.pop(fut)
                    exc = fut.exception()
                    on_result(t.index, exc if exc is not None else fut.result())
                check()
                self._overdue(tasks)
        except BaseException:
            running = self._drop(job, [t for t in tasks if not t.done.done()])
            if running:
                log.info("job %s: dropped %d running candidate(s)", job, running)
            raise

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._queues.clear()
            for slot in self._slots:
                slot.kill()


__all__ = ["POLL_S", "FairPool"]
