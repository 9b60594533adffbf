"""The embedded default's evaluation processes: the one process pool (`optim.procpool.SlotPool`)
shared fairly by jobs, whose running candidates can be dropped.

`FairPool(workers)` is a `SlotPool` of `workers` slots started from a fork server that has
imported the simulator (`optim.procpool.SIMULATOR_PRELOAD`), whose processes ignore group
signals (SIGINT, SIGTERM: Ctrl-C or `kill -- -PGID` stops the server, which ends its slots; it
never looks like a crash) and exit within `optim.procpool.PARENT_WATCH_S` once the server is
gone.
`run(job, fn, batch, check, on_result)` queues the job's candidates; whenever a slot is free the
next candidate is taken round robin over the jobs that have some queued (a job not served yet
first), so a small job sent after a huge one starts as soon as one running candidate ends.

Contracts (`SlotPool.run`'s):
  * `on_result(i, outcome)` is called in the caller's thread as each candidate finishes, in
    completion order, with an `EvalOutcome` or an `EvaluationError` (its process died: crash,
    out of memory, killed; or it ran past `time_limit` and was killed). An exception inside
    `fn` is an outcome with `error` set (`optim.procpool.evaluate_one`), as everywhere.
  * `check()` is called at least every `POLL_S` while waiting; if it raises, the job's queued
    candidates are removed, the slots running its candidates are killed (their processes
    restart at once) and the exception propagates: a cancelled or stopped job costs no more CPU
    within a poll.
  * `cut_margin` and `done` (the values of the generation's candidates finished before): the
    rank-preserving cut of the generation's last candidate (`optim.rankcut`), as on the
    command line.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from optim.procpool import POLL_S, SIMULATOR_PRELOAD, OnResult, SlotPool

#: Start method of the slot processes: a fork server (started like "spawn", so no thread or
#: ODE state of the server is inherited) that has imported `SIMULATOR_PRELOAD`.
DEFAULT_SLOT_START_METHOD = "forkserver"


class FairPool(SlotPool):
    """See the module docstring. Thread-safe: several job drivers share one pool."""

    def __init__(self, workers: int, *, time_limit: float | None = None,
                 start_method: str = DEFAULT_SLOT_START_METHOD) -> None:
        super().__init__(workers, start_method=start_method, preload=SIMULATOR_PRELOAD,
                         time_limit=time_limit, ignore_signals=True)

    def run(self, job: str, fn: Any, batch: Sequence[np.ndarray],  # type: ignore[override]
            check: Callable[[], None], on_result: OnResult, *,
            cut_margin: float | None = None, done: Sequence[float] = ()) -> None:
        """Evaluate `batch` for `job` (see the module docstring)."""
        super().run(job, fn, batch, on_result, check=check, cut_margin=cut_margin, done=done)


__all__ = ["POLL_S", "FairPool"]
