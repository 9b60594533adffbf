"""Executors: order, error outcomes, dead workers, timeouts, serial == pool."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from proc_helpers import child_env
from synthetic import KillWorker, RaiseAbove, Sleep, Sphere

from optim.cmaes import FAILED_OBJECTIVE, CmaOptimizer, StopRules
from optim.errors import EvaluationError
from optim.executors import (
    PARENT_WATCH_S,
    EvalOutcome,
    PoolExecutor,
    SerialExecutor,
    make_executor,
)


def plain_float(x: np.ndarray) -> float:
    return float(np.sum(x))


def run_cma(executor, fn, seed=5, gens=6):
    opt = CmaOptimizer(6, seed=seed, rules=StopRules(max_evaluations=10_000))
    outs_all = []
    for _ in range(gens):
        xs = opt.ask()
        outs = executor.map(fn, xs)
        outs_all.append([(o.objective, o.fell, o.error) for o in outs])
        opt.tell(xs, [o.objective for o in outs])
    return opt, outs_all


@pytest.fixture(scope="module")
def pool2():
    with PoolExecutor(2, timeout=30.0) as ex:
        yield ex


def test_serial_in_order_and_errors_become_outcomes():
    batch = [np.array([v, 0.0]) for v in (0.1, 0.9, 0.2)]
    with SerialExecutor() as ex:
        outs = ex.map(RaiseAbove(limit=0.5), batch)
        assert [o.error is None for o in outs] == [True, False, True]
        assert outs[1].objective == FAILED_OBJECTIVE and "ValueError" in outs[1].error
        assert outs[0].objective == pytest.approx(0.04 + 0.09)
        floats = ex.map(plain_float, batch)
        assert [o.objective for o in floats] == [0.1, 0.9, 0.2]
        assert all(isinstance(o, EvalOutcome) for o in floats)


def test_pool_matches_serial_for_any_worker_count(pool2):
    fn = Sphere(centre=0.25, fall_above=0.5)
    ref_opt, ref_outs = run_cma(SerialExecutor(), fn)
    with PoolExecutor(1, timeout=30.0) as pool1:
        for ex in (pool1, pool2):
            opt, outs = run_cma(ex, fn)
            assert outs == ref_outs
            assert opt.history == ref_opt.history
            np.testing.assert_array_equal(opt.best_x, ref_opt.best_x)


def test_pool_reports_errors_like_serial(pool2):
    batch = [np.array([v, 0.0]) for v in (0.1, 0.9, 0.2)]
    s = SerialExecutor().map(RaiseAbove(), batch)
    p = pool2.map(RaiseAbove(), batch)
    assert [(o.objective, o.error) for o in s] == [(o.objective, o.error) for o in p]


def test_dead_worker_raises_evaluation_error_and_pool_recovers():
    with PoolExecutor(2, timeout=30.0) as ex:
        t0 = time.monotonic()
        with pytest.raises(EvaluationError, match="worker process died"):
            ex.map(KillWorker(), [np.zeros(2)] * 3)
        assert time.monotonic() - t0 < 20
        outs = ex.map(Sphere(centre=0.0), [np.ones(2)])  # a fresh pool serves the next batch
        assert outs[0].objective == 2.0


def test_batch_timeout_raises_and_kills_workers():
    with PoolExecutor(1, timeout=0.5) as ex:
        ex.map(Sphere(), [np.zeros(2)])  # warm up the spawned worker
        t0 = time.monotonic()
        with pytest.raises(EvaluationError, match="timed out"):
            ex.map(Sleep(30.0), [np.zeros(2)])
        assert time.monotonic() - t0 < 10


def test_make_executor():
    assert isinstance(make_executor(1), SerialExecutor)
    ex = make_executor(2)
    assert isinstance(ex, PoolExecutor) and ex.workers == 2
    ex.close()
    with pytest.raises(EvaluationError, match="closed"):
        ex.map(Sphere(), [np.zeros(1)])


def _gone(pid: int) -> bool:
    """True once `pid` has exited (a zombie waiting for its reaper counts as exited)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return any(line.startswith("State:") and "Z" in line.split()[1] for line in f)
    except FileNotFoundError:
        return True


POOL_PARENT = """
import os, sys, time
import numpy as np
from optim.executors import PoolExecutor
from synthetic import Sphere
pool = PoolExecutor(2)
pool.map(Sphere(), [np.zeros(2), np.ones(2)])
print(" ".join(str(p) for p in pool.pids()), flush=True)
time.sleep(600)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pool_workers_exit_when_their_parent_is_killed():
    """SIGKILL runs no clean-up in the parent: its workers notice and exit by themselves
    (before, they waited on the call queue for ever, 200 MB each)."""
    proc = subprocess.Popen([sys.executable, "-c", POOL_PARENT], stdout=subprocess.PIPE,
                            text=True, cwd=Path(__file__).resolve().parents[2], env=child_env())
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert len(workers) == 2 and not any(_gone(p) for p in workers)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    deadline = time.monotonic() + 10 * PARENT_WATCH_S + 5.0
    while not all(_gone(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert all(_gone(p) for p in workers), workers
