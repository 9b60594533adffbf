"""The one process pool: slots, a fair queue, time limits, kill, restart and a parent watch.

Used by the command line (`optim.executors.PoolExecutor`), the embedded service's evaluation
pool (`worker.fairpool.FairPool`) and the API's what-if simulations
(`application.simulations.SimulationPool`); the last two start their slots from a fork server
that has imported `SIMULATOR_PRELOAD`.

`SlotPool(workers)` keeps `workers` single-process slots, each its own one-process
`concurrent.futures.ProcessPoolExecutor`, so that one slot can be killed (a time limit, a
cancelled job) without touching the others. `submit(fn, *args, group=...)` queues a call; a free
slot takes the next one round robin over the groups that have some queued, a group not served
yet first (a small job sent after a huge one starts as soon as one running call ends, never after
the huge job's whole batch). With one group this is first in, first out.

Contracts:
  * `submit` returns a `SlotTask` whose `future` gets `fn(*args)`'s value or exception, or a
    `WorkerDiedError` (the slot's process died: crash, out of memory, killed; the slot restarts on
    next use) or a `TimeLimitError` (the call ran past its time limit: the slot's process is
    killed).
  * `drop(tasks)` removes queued tasks and kills the slots running any of them (each restarted
    at once, so its imports overlap the wait for the next call); their futures get `DroppedError`.
  * `run(group, fn, batch, on_result, ...)` evaluates a batch of candidates
    (`optim.executors.evaluate_one`: an exception inside `fn` is an outcome with `error` set),
    calling `on_result(i, outcome | EvaluationError)` in the caller's thread in completion
    order and `check()` at least every `POLL_S`; if `check` raises, the batch's unfinished
    tasks are dropped and the exception propagates. With `cut_margin` (`optim.rankcut`) the
    last unfinished candidate stops early once it certainly ranks last: its bound reaches its
    slot's process through that slot's own shared `[key, bound]` array, written under the
    pool's lock only while the slot runs that very task, so no other call ever reads it.
  * Slot processes exit by themselves within PARENT_WATCH_S once the process that made the pool
    is gone (killed with SIGKILL, say, where no clean-up runs), instead of waiting on their
    queue for ever; with `ignore_signals` they also ignore SIGINT and SIGTERM (a signal to the
    whole process group stops the parent, which ends its slots; it never looks like a crash).
  * Thread-safe: several callers (job drivers, family members, API requests) share one pool.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import itertools
import math
import multiprocessing
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from optim.errors import EvaluationError
from optim.outcome import FAILED_OBJECTIVE, CuttableObjective, EvalOutcome, Objective
from optim.rankcut import bound_for_last

#: How often a slot process checks that the process that made the pool is still alive, s.
PARENT_WATCH_S = 0.5
#: Longest wait between two `check()` calls in `run`, and the time limits' resolution, s.
POLL_S = 0.1
#: What a fork server imports before it forks slot processes (`set_forkserver_preload`): the
#: simulator, and `optim.slotwarm`, whose one tiny simulation loads its compiled code, so a slot
#: killed past its time limit is replaced in a fraction of a second.
SIMULATOR_PRELOAD = ("numpy", "optim.objective", "optim.spline", "sim.rollout", "optim.procpool",
                     "optim.slotwarm")

OnResult = Callable[[int, "EvalOutcome | EvaluationError"], None]


class WorkerDiedError(EvaluationError):
    """The slot process running the call died (crash, out of memory, killed)."""


class TimeLimitError(EvaluationError):
    """The call ran past its time limit; its slot process was killed."""


class DroppedError(EvaluationError):
    """The call was dropped (`SlotPool.drop`) before it finished."""


# -- in the slot processes --------------------------------------------------------------------

def evaluate_one(fn: Objective, params: np.ndarray, **kwargs: Any) -> EvalOutcome:
    """Run `fn(params)`, turning a float into an outcome and an exception into an error outcome
    (a property of the candidate: it ranks last, the batch goes on)."""
    t0 = time.process_time()
    try:
        out = fn(params, **kwargs)
    except Exception as err:  # noqa: BLE001 - reported per candidate
        return EvalOutcome(objective=FAILED_OBJECTIVE, fell=False,
                           cpu_seconds=time.process_time() - t0,
                           error=f"{type(err).__name__}: {err}")
    if isinstance(out, EvalOutcome):
        return out
    return EvalOutcome(objective=float(out), cpu_seconds=time.process_time() - t0)


#: This slot process' shared [key, bound] array (set by the initializer), None elsewhere.
_CUT_SHARED: Any = None


def _bound_reader(shared: Any, key: float) -> Callable[[], float]:
    """A `stop_above` reading the bound posted for task `key` (the parent writes the bound
    before the key): inf until it is posted."""

    def read() -> float:
        k1 = shared[0]
        b = shared[1]
        if k1 == key and shared[0] == key:
            return b
        return math.inf

    return read


def evaluate_one_cuttable(fn: Objective, params: np.ndarray, key: float) -> EvalOutcome:
    """`evaluate_one` in a slot process, `fn` stopping early once the parent posts a bound for
    task `key` that its objective's lower bound exceeds (`optim.rankcut`)."""
    if _CUT_SHARED is None:
        return evaluate_one(fn, params)
    return evaluate_one(fn, params, stop_above=_bound_reader(_CUT_SHARED, key))


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


def exit_with(owner_pid: int) -> None:
    """A daemon thread ends this process once `owner_pid` is gone. Watching the owner itself,
    not the parent: a fork server's children have the fork server as parent, and it outlives
    an owner killed with SIGKILL while its children live; a spawned child's queue never sees an
    end of file either (every child holds its write end too)."""

    def watch() -> None:
        while _alive(owner_pid):
            time.sleep(PARENT_WATCH_S)
        os._exit(1)  # nobody is left to want the result

    threading.Thread(target=watch, name="cmrt-owner-watch", daemon=True).start()


def _slot_init(owner_pid: int, ignore_signals: bool, shared: Any) -> None:
    global _CUT_SHARED
    _CUT_SHARED = shared
    if ignore_signals:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    exit_with(owner_pid)


def _ping() -> int:
    return os.getpid()


def kill_process_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Kill a process pool's processes (SIGKILL) and shut it down without waiting."""
    # the executor's private process table: the only handle on its processes (None once shut)
    procs = list((pool._processes or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.kill()
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5.0)


# -- in the owner -----------------------------------------------------------------------------

@dataclass(eq=False)
class SlotTask:
    """One queued or running call; `future` resolves as the module docstring says."""

    group: Hashable
    index: int
    fn: Callable[..., Any]
    args: tuple[Any, ...]
    time_limit: float | None
    key: float = 0.0
    future: cf.Future = field(default_factory=cf.Future)
    started: float | None = None
    bound: float | None = None  # the cut bound to post when it starts (None: none yet)

    def resolve(self, value: Any = None, error: BaseException | None = None) -> None:
        if self.future.done():
            return
        if error is not None:
            self.future.set_exception(error)
        else:
            self.future.set_result(value)


class _Slot:
    def __init__(self, number: int, pool: SlotPool) -> None:
        self.number, self._pool = number, pool
        self.executor: cf.ProcessPoolExecutor | None = None
        self.task: SlotTask | None = None
        self.shared = pool._ctx.RawArray("d", [-1.0, math.inf])  # [key, bound] of its task

    def start(self) -> cf.ProcessPoolExecutor:
        if self.executor is None:
            p = self._pool
            self.executor = cf.ProcessPoolExecutor(
                max_workers=1, mp_context=p._ctx, initializer=_slot_init,
                initargs=(os.getpid(), p._ignore_signals, self.shared))
        return self.executor

    def post(self, task: SlotTask) -> None:
        """Write `task`'s bound for its process (the bound before the key: `_bound_reader`)."""
        if task.bound is not None:
            self.shared[1] = task.bound
            self.shared[0] = task.key

    def pids(self) -> list[int]:
        ex = self.executor
        return [] if ex is None else list(ex._processes or {})  # private, as kill_process_pool

    def kill(self, *, restart: bool = False) -> None:
        """Kill the slot's process; with `restart` start its successor at once (its imports
        then overlap the wait for the next call)."""
        ex, self.executor, self.task = self.executor, None, None
        if restart:
            with contextlib.suppress(Exception):
                self.start().submit(_ping)
        if ex is not None:
            kill_process_pool(ex)


class SlotPool:
    """See the module docstring.

    workers: slots (processes). start_method: "spawn" (default), "forkserver" (with `preload`:
    modules the fork server imports once, so a killed slot's successor is a fork of it,
    milliseconds, instead of a fresh interpreter importing everything) or "fork".
    time_limit: default wall-clock limit of one call, s (None: none). ignore_signals: slot
    processes ignore SIGINT and SIGTERM.
    """

    def __init__(self, workers: int, *, start_method: str = "spawn",
                 preload: Sequence[str] = (), time_limit: float | None = None,
                 ignore_signals: bool = False) -> None:
        if workers < 1:
            raise ValueError(f"a process pool needs at least 1 worker, got {workers}")
        if time_limit is not None and time_limit <= 0:
            raise ValueError("the time limit must be positive seconds or None")
        self._ctx = multiprocessing.get_context(start_method)
        if start_method == "forkserver" and preload:
            self._ctx.set_forkserver_preload(list(preload))
        self._ignore_signals = ignore_signals
        self.time_limit = time_limit
        self._slots = [_Slot(i, self) for i in range(int(workers))]
        #: Each group's queued calls, in serving order (a dict keeps its insertion order).
        self._queues: dict[Hashable, deque[SlotTask]] = {}
        self._lock = threading.RLock()
        self._closed = False
        self._keys = itertools.count(1)
        self._watchdog: threading.Thread | None = None
        #: Calls started, per group (for tests and /health).
        self.started: dict[Hashable, int] = {}

    @property
    def workers(self) -> int:
        return len(self._slots)

    @property
    def closed(self) -> bool:
        return self._closed

    def pids(self) -> list[int]:
        """The slot processes' ids (started slots only)."""
        with self._lock:
            return [pid for s in self._slots for pid in s.pids()]

    def warm_up(self, timeout: float) -> None:
        """Start every slot's process (imports) and wait for it, before any time limit runs;
        raises EvaluationError (every slot killed) when one does not start within `timeout` s."""
        with self._lock:
            self._check_open()
            futures = [s.start().submit(_ping) for s in self._slots]
        done, not_done = cf.wait(futures, timeout=timeout)
        try:
            if not_done:
                raise EvaluationError(f"worker processes did not start within {timeout:g} s")
            for fut in done:
                fut.result()
        except BrokenProcessPool:
            self._kill_all()
            raise EvaluationError("a worker process died while starting") from None
        except EvaluationError:
            self._kill_all()
            raise

    # -- queue (under the lock) ----------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise EvaluationError("the process pool is closed")

    def _next_task(self) -> SlotTask | None:
        for group in list(self._queues):
            q = self._queues[group]
            while q and q[0].future.done():  # cancelled by its caller while queued
                q.popleft()
            if q:
                task = q.popleft()
                self._queues[group] = self._queues.pop(group)  # round robin: to the back
                return task
            del self._queues[group]
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
                self.started[task.group] = self.started.get(task.group, 0) + 1
                slot.task = task
                task.started = time.monotonic()
                slot.post(task)
                try:
                    fut = slot.start().submit(task.fn, *task.args)
                except BrokenProcessPool:
                    slot.kill()
                    task.resolve(error=WorkerDiedError(
                        f"the worker process of slot {slot.number} died before the call "
                        "started"))
                    continue
                fut.add_done_callback(lambda f, s=slot, t=task: self._finished(s, t, f))
            self._ensure_watchdog()

    def _finished(self, slot: _Slot, task: SlotTask, fut: cf.Future) -> None:
        with self._lock:
            if slot.task is task:
                slot.task = None
            if not task.future.done():
                try:
                    task.resolve(fut.result())
                except BrokenProcessPool:
                    slot.kill()
                    task.resolve(error=WorkerDiedError(
                        f"the worker process evaluating call {task.index} died (crash, out of "
                        "memory or killed)"))
                except cf.CancelledError:
                    task.resolve(error=DroppedError(f"call {task.index} was cancelled in the pool"))
                except Exception as err:  # noqa: BLE001 - fn's own error, or not picklable
                    task.resolve(error=err)
        self._dispatch()

    def _ensure_watchdog(self) -> None:
        """Start the time limits' watchdog thread if a running call has a limit."""
        if self._watchdog is not None and self._watchdog.is_alive():
            return
        if not any(s.task is not None and s.task.time_limit is not None for s in self._slots):
            return
        self._watchdog = threading.Thread(target=self._watch, name="cmrt-pool-limits",
                                          daemon=True)
        self._watchdog.start()

    def _watch(self) -> None:
        while True:
            time.sleep(POLL_S)
            now = time.monotonic()
            with self._lock:
                if self._closed:
                    return
                limited = False
                for slot in self._slots:
                    t = slot.task
                    if t is None or t.time_limit is None or t.started is None:
                        continue
                    limited = True
                    if now - t.started > t.time_limit:
                        slot.kill()
                        t.resolve(error=TimeLimitError(
                            f"candidate {t.index} ran past the time limit of "
                            f"{t.time_limit:g} s and its worker process was killed"))
                if not limited:
                    self._watchdog = None
                    return
            self._dispatch()

    # -- the callers' side ---------------------------------------------------------------------
    def submit(self, fn: Callable[..., Any], *args: Any, group: Hashable = None,
               index: int = 0, time_limit: float | None | str = "default") -> SlotTask:
        """Queue `fn(*args)` for `group` (see the module docstring); `time_limit` "default":
        the pool's."""
        return self.submit_many(group, [(fn, args)], index=index, time_limit=time_limit)[0]

    def submit_many(self, group: Hashable, calls: Iterable[tuple[Callable[..., Any],
                                                                 tuple[Any, ...]]],
                    *, index: int = 0, time_limit: float | None | str = "default",
                    keys: Sequence[float] | None = None) -> list[SlotTask]:
        """Queue several calls of `group` at once, indexed from `index`; `keys`: the tasks'
        cut keys (`new_keys`), else fresh ones."""
        limit = self.time_limit if time_limit == "default" else time_limit
        calls = list(calls)
        if keys is None:
            keys = self.new_keys(len(calls))
        with self._lock:
            self._check_open()
            tasks = [SlotTask(group, index + i, fn, tuple(args), limit, key)  # type: ignore[arg-type]
                     for i, ((fn, args), key) in enumerate(zip(calls, keys, strict=True))]
            if group not in self._queues:  # a group not served yet goes first
                self._queues = {group: deque(), **self._queues}
            self._queues[group].extend(tasks)
        self._dispatch()
        return tasks

    def new_keys(self, n: int) -> list[float]:
        """`n` task keys never used in this pool (a cuttable call is given its own)."""
        with self._lock:
            return [float(next(self._keys)) for _ in range(n)]

    def set_bound(self, task: SlotTask, bound: float) -> None:
        """Let `task` (submitted through `evaluate_one_cuttable`) stop once its objective's
        lower bound exceeds `bound`: posted to its slot now if it runs, else when it starts."""
        with self._lock:
            task.bound = bound
            for slot in self._slots:
                if slot.task is task:
                    slot.post(task)

    def drop(self, tasks: Sequence[SlotTask]) -> int:
        """Remove the queued `tasks` and kill the slots running any of them (restarted at
        once); returns how many were running. Their futures get `DroppedError`."""
        killed = 0
        doomed = set(tasks)
        with self._lock:
            for group in {t.group for t in tasks}:
                q = self._queues.get(group)
                if q is not None:
                    self._queues[group] = deque(t for t in q if t not in doomed)
            for slot in self._slots:
                if slot.task is not None and slot.task in doomed:
                    slot.kill(restart=not self._closed)
                    killed += 1
            for t in tasks:
                t.resolve(error=DroppedError(f"call {t.index} was dropped"))
        self._dispatch()
        return killed

    def run(self, group: Hashable, fn: Objective, batch: Sequence[np.ndarray],
            on_result: OnResult, *, check: Callable[[], None] | None = None,
            timeout: float | None = None, cut_margin: float | None = None,
            done: Sequence[float] = ()) -> bool:
        """Evaluate `batch` for `group` (see the module docstring); returns False when the
        batch ran past `timeout` s (its unfinished candidates dropped, not reported).

        cut_margin: not None, when `fn` is a `CuttableObjective` and the batch and `done` (the
        objective values of the generation's candidates finished before this batch) hold at
        least two candidates, lets the last unfinished one stop early (`optim.rankcut`)."""
        xs = [np.asarray(x, dtype=float) for x in batch]
        cut = (cut_margin is not None and isinstance(fn, CuttableObjective)
               and len(xs) + len(done) >= 2)
        keys = self.new_keys(len(xs))
        if cut:  # the key the slot reads is the one its call was given
            calls = [(evaluate_one_cuttable, (fn, x, k)) for x, k in zip(xs, keys, strict=True)]
        else:
            calls = [(evaluate_one, (fn, x)) for x in xs]
        tasks = self.submit_many(group, calls, keys=keys)
        values = list(done)
        deadline = None if timeout is None else time.monotonic() + timeout
        waiting = {t.future: t for t in tasks}
        failed = False  # a candidate without a value: no bound can be given
        try:
            while waiting:
                left = POLL_S if deadline is None else min(POLL_S, deadline - time.monotonic())
                finished, _ = cf.wait(list(waiting), timeout=max(0.0, left),
                                      return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    t = waiting.pop(fut)
                    exc = fut.exception()
                    out = exc if exc is not None else fut.result()
                    if isinstance(out, EvalOutcome):
                        values.append(out.objective)
                    else:
                        failed = True
                    on_result(t.index, out)  # type: ignore[arg-type]
                if cut and not failed and len(waiting) == 1:
                    last = next(iter(waiting.values()))
                    if last.bound is None:
                        self.set_bound(last, bound_for_last(values, cut_margin))  # type: ignore[arg-type]
                if check is not None:
                    check()
                if waiting and deadline is not None and time.monotonic() >= deadline:
                    self.drop(list(waiting.values()))
                    return False
        except BaseException:
            self.drop([t for t in waiting.values()])
            raise
        return True

    def _kill_all(self) -> None:
        with self._lock:
            for slot in self._slots:
                if slot.task is not None:
                    slot.task.resolve(error=DroppedError("the pool was restarted"))
                slot.kill()

    def close(self) -> None:
        """Drop every queued call and end every slot's process; the pool cannot be used
        afterwards."""
        with self._lock:
            self._closed = True
            queued = [t for q in self._queues.values() for t in q]
            self._queues.clear()
            for t in queued:
                t.resolve(error=DroppedError("the process pool was closed"))
        self._kill_all()


__all__ = [
    "PARENT_WATCH_S",
    "POLL_S",
    "SIMULATOR_PRELOAD",
    "DroppedError",
    "SlotPool",
    "SlotTask",
    "TimeLimitError",
    "WorkerDiedError",
    "evaluate_one",
    "evaluate_one_cuttable",
    "exit_with",
    "kill_process_pool",
]
