"""The rank-preserving early stop (optim.rankcut): runs with and without it are identical."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from synthetic import RunningSum

from optim import rankcut
from optim.executors import Executor, PoolExecutor, SerialExecutor
from optim.loop import SearchSpace, final_evaluation, new_optimizer, run_generations
from optim.outcome import EvalOutcome
from optim.procpool import SlotPool
from optim.run import BatchEvaluator, optimize
from sim import load_spec


class Recorder:
    """RunState that keeps every generation's strategy figures (no restore)."""

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def restore(self):  # noqa: ANN201 - protocol
        return None

    def save(self, opt, generation, stats, candidates, wall_seconds) -> None:  # noqa: ANN001
        d = dataclasses.asdict(stats)
        d.pop("worst")  # a lower bound when the last was cut: the one figure that may differ
        self.rows.append({"stats": d, "mean": opt.mean.tobytes(), "sigma": opt.sigma,
                          "C": np.array(opt._s.es.C, dtype=float).tobytes(),
                          "x": [np.asarray(c).tobytes() for c in candidates]})


class Counting(BatchEvaluator):
    """BatchEvaluator counting cut outcomes and simulated seconds."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003
        super().__init__(*args, **kwargs)
        self.cuts = 0
        self.sim_seconds = 0.0

    def evaluate(self, generation, candidates):  # noqa: ANN001, ANN201
        outs = super().evaluate(generation, candidates)
        self.cuts += sum(o.cut for o in outs)
        self.sim_seconds += sum(o.sim_seconds for o in outs)
        return outs


def _run(spec, executor, fn, cut: bool, seed: int = 3):  # noqa: ANN001, ANN202
    space = SearchSpace.of(spec)
    opt = new_optimizer(spec, space, seed)
    ev = Counting(executor, fn, opt.cut_margin if cut else None)
    rec = Recorder()
    stop = run_generations(opt, space, ev, rec)
    final = final_evaluation(opt, space, ev)
    return rec.rows, stop, final, ev


def _synthetic_spec(max_evaluations: int):  # noqa: ANN202
    spec = load_spec("examples/fast_bend.yaml")
    return spec.model_copy(update={"optimize": spec.optimize.model_copy(
        update={"threshold": None, "max_evaluations": max_evaluations, "min_evaluations": 0,
                "window": 5})})


class LastAlonePool(Executor):
    """Two processes of the one process pool (`optim.procpool.SlotPool`) evaluating a
    generation's last candidate alone, once the others are done, given their values (`done`,
    as a resumed generation's are) and holding it until its bound is posted (`RunningSum.hold`):
    the pool's cut path (the bound posted to a running process, read there), with the cut
    decided by the values alone, as the serial executor's."""

    def __init__(self, workers: int = 2) -> None:
        self.pool = SlotPool(workers)
        self.groups = itertools.count()

    def map(self, fn, batch, cut_margin=None):  # noqa: ANN001, ANN201
        out: list = [None] * len(batch)

        def put(offset: int):  # noqa: ANN202
            return lambda i, o: out.__setitem__(offset + i, o)

        if cut_margin is None or len(batch) < 2:
            self.pool.run(next(self.groups), fn, batch, put(0))
        else:
            self.pool.run(next(self.groups), fn, batch[:-1], put(0))
            done = [o.objective for o in out[:-1]]
            self.pool.run(next(self.groups), dataclasses.replace(fn, hold=60.0), batch[-1:],
                          put(len(batch) - 1), cut_margin=cut_margin, done=done)
        assert all(isinstance(o, EvalOutcome) for o in out), out
        return out

    def close(self) -> None:
        self.pool.close()


@pytest.mark.parametrize("executor", ["serial", "pool-last-alone", "pool"])
def test_cut_keeps_the_run_identical_synthetic(executor: str) -> None:
    """Serial: the last candidate is cut when it ranks last. Pool, last alone: the same cuts
    (the same simulated seconds) through the pool's bound posted to a running process. Pool
    (2 workers, one pool for both runs): whichever candidate is left last, timing decides which
    cuts happen (maybe none on a busy machine); the run is identical whatever they are."""
    spec = _synthetic_spec(300 if executor == "serial" else 150)
    fn = (RunningSum(steps=200) if executor == "serial"
          else RunningSum(steps=200, check_every=20, sleep=1e-3))
    make = {"serial": SerialExecutor, "pool-last-alone": LastAlonePool,
            "pool": lambda: PoolExecutor(2)}[executor]
    with make() as ex:
        rows_a, stop_a, fin_a, ev_a = _run(spec, ex, fn, cut=False)
        rows_b, stop_b, fin_b, ev_b = _run(spec, ex, fn, cut=True)
    assert ev_a.cuts == 0
    if executor == "pool":
        assert ev_b.sim_seconds <= ev_a.sim_seconds  # a cut only ever saves steps
    else:
        assert ev_b.cuts >= 1  # the cut happened
        assert ev_b.sim_seconds < ev_a.sim_seconds
    if executor == "pool-last-alone":  # cut exactly where the serial run cuts
        with SerialExecutor() as ex:
            _rows, _stop, _fin, ev_s = _run(spec, ex, dataclasses.replace(fn, sleep=0.0),
                                            cut=True)  # timing changes no value in series
        assert (ev_b.cuts, ev_b.sim_seconds) == (ev_s.cuts, ev_s.sim_seconds)
    assert len(rows_a) == len(rows_b) >= 10
    assert rows_a == rows_b  # every generation's mean, sigma, C, candidates, best, median
    assert stop_a == stop_b
    assert fin_a.best.objective == fin_b.best.objective and fin_a.winner == fin_b.winner
    assert fin_a.best_params.tobytes() == fin_b.best_params.tobytes()


def test_cut_keeps_the_run_identical_simulated() -> None:
    """Seeded, small: the fast bend, popsize 4, 3 generations, serial. Seed 3 with sigma0
    0.03 has a generation whose last candidate stands and ranks last (most seeds' small runs
    have none: a fall anywhere in a generation rules the cut out, see optim.rankcut)."""
    spec = load_spec("examples/fast_bend.yaml")
    spec = spec.model_copy(update={"optimize": spec.optimize.model_copy(
        update={"popsize": 4, "max_evaluations": 12, "sigma0": 0.03})})
    res = {}
    for cut in (False, True):
        with SerialExecutor() as ex:
            seen = []
            r = optimize(spec, ex, seed=3, cut=cut, progress=seen.append)
        res[cut] = r
    a, b = res[False].to_dict(), res[True].to_dict()
    a["history"] = [{k: v for k, v in h.items() if k != "worst"} for h in a["history"]]
    b["history"] = [{k: v for k, v in h.items() if k != "worst"} for h in b["history"]]
    a.pop("wall_seconds"), b.pop("wall_seconds")
    assert a == b
    # the cut happened in this run: some generation's recorded worst is a lower bound
    worst_a = [h["worst"] for h in res[False].to_dict()["history"]]
    worst_b = [h["worst"] for h in res[True].to_dict()["history"]]
    assert any(wb < wa for wa, wb in zip(worst_a, worst_b, strict=True))
    assert all(wb <= wa for wa, wb in zip(worst_a, worst_b, strict=True))


def test_rollout_cut_is_a_lower_bound_and_no_cut_changes_nothing() -> None:
    from sim.rollout import Rollout

    spec = load_spec("examples/fast_bend.yaml")
    sim = Rollout(spec)
    full = sim.run(None)
    above = sim.run(None, stop_above=lambda: full.objective)  # never exceeded: not cut
    assert {**above.__dict__, "cpu_seconds": 0} == {**full.__dict__, "cpu_seconds": 0}
    cut = sim.run(None, stop_above=lambda: 0.5 * full.objective)
    assert cut.cut and 0.5 * full.objective < cut.objective <= full.objective
    assert cut.steps < full.steps
    sim.close()


def test_verify_rules() -> None:
    o = EvalOutcome
    assert rankcut.verify([o(1.0), o(2.0)], 1e-11)
    assert rankcut.verify([o(1.0), o(3.0, cut=True)], 1e-11)
    assert not rankcut.verify([o(1.0), o(3.0, cut=True)], None)
    assert not rankcut.verify([o(3.0), o(3.0, cut=True)], 1e-11)  # not strictly last
    assert not rankcut.verify([o(1.0), o(3.0, cut=True), o(4.0, cut=True)], 1e-11)
    assert not rankcut.verify([o(1.0), o(1.0 + 1e-13, cut=True)], 1e-11)  # tolfun margin
    assert rankcut.bound_for_last([1.0, 2.0], 1e-11) == 2.0
    assert rankcut.bound_for_last([], 1e-11) == math.inf
