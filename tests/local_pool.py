"""Test seams for the local pool (`worker.executors.LocalPoolExecutor`): `local_executor` builds
one whose evaluations run through a given optim `Executor` (`BatchPool`: a serial executor,
no process pool) or `FairPool`, and whose jobs' objectives come from `factory` (typed spec ->
objective; None: the simulation)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from cmrt.settings import Settings
from optim.errors import EvaluationError
from optim.executors import Executor
from worker.candidates import JobSpecs
from worker.executors import LocalPoolExecutor
from worker.fairpool import FairPool


class BatchPool:
    """A `FairPool` stand-in over an optim `Executor` (one batch per call; a failed batch
    counts as every candidate's process dying)."""

    def __init__(self, executor: Executor) -> None:
        self.executor = executor

    @property
    def workers(self) -> int:
        return self.executor.workers

    def run(self, job, fn, batch, check, on_result, *, cut_margin=None, done=()) -> None:
        check()
        try:  # the executor's bound knows only the batch: no cut beside stored values
            outs: list[Any] = self.executor.map(fn, list(batch),
                                                cut_margin=None if done else cut_margin)
        except EvaluationError as err:
            outs = [err] * len(batch)
        for i, out in enumerate(outs):
            on_result(i, out)

    def close(self) -> None:
        self.executor.close()


class FactorySpecs(JobSpecs):
    """`JobSpecs` whose jobs' objectives are `factory(typed spec)`, made once per spec."""

    def __init__(self, factory: Callable[[Any], Any]) -> None:
        super().__init__()
        self.factory = factory
        self._made: dict[str, Any] = {}

    def get(self, repo: Any, job_id: str) -> tuple[Any, Any]:
        spec, sim = super().get(repo, job_id)
        if sim.spec_hash not in self._made:
            self._made[sim.spec_hash] = self.factory(spec)
        return spec, self._made[sim.spec_hash]


def local_executor(config: Settings, pool: Executor | FairPool,
                   factory: Callable[[Any], Any] | None = None) -> LocalPoolExecutor:
    """A LocalPoolExecutor over `pool` (its own FairPool, never started, closed)."""
    ex = LocalPoolExecutor(config)
    ex.pool.close()
    ex.pool = pool if isinstance(pool, FairPool) else BatchPool(pool)  # type: ignore[assignment]
    ex.cache = JobSpecs() if factory is None else FactorySpecs(factory)
    return ex
