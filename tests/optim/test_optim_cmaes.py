"""CMA-ES wrapper: stopping rules, determinism, own RNG, pickled resume."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest
from synthetic import NoisyFlat, Sphere

from optim.cmaes import CmaOptimizer, GenerationStats, StopRules
from optim.errors import CheckpointError


def drive(opt: CmaOptimizer, fn, max_gens: int = 10_000) -> str | None:
    for _ in range(max_gens):
        reason = opt.stop()
        if reason is not None:
            return reason
        xs = opt.ask()
        opt.tell(xs, [fn(x).objective for x in xs])
    return None


def test_threshold_rule_on_sphere():
    rules = StopRules(threshold=1e-3, max_evaluations=5000)
    opt = CmaOptimizer(4, seed=1, rules=rules)
    assert drive(opt, Sphere(centre=0.3)) == "threshold"
    assert opt.best_f <= 1e-3
    np.testing.assert_allclose(opt.best_x, 0.3, atol=0.05)
    assert opt.evaluations == opt.iterations * opt.popsize
    assert opt.history[-1].best_so_far == opt.best_f


def test_slow_convergence_rule_on_noisy_flat():
    rules = StopRules(min_evaluations=200, window=10, improvement=0.05, max_evaluations=10_000)
    opt = CmaOptimizer(8, seed=2, rules=rules)
    assert drive(opt, NoisyFlat(amplitude=0.01)) == "slow_convergence"
    assert opt.evaluations >= 200
    assert opt.iterations >= 11
    # it fires at the first generation where both conditions hold
    assert opt.evaluations - opt.popsize < 200 or opt.iterations == 11


def test_slow_convergence_waits_for_min_evaluations():
    rules = StopRules(min_evaluations=700, window=5, max_evaluations=10_000)
    opt = CmaOptimizer(8, seed=2, rules=rules)
    assert drive(opt, NoisyFlat()) == "slow_convergence"
    assert 700 <= opt.evaluations < 700 + opt.popsize


@pytest.mark.parametrize("rules", [
    StopRules(min_evaluations=200, window=10, improvement=0.05, max_evaluations=10_000),
    StopRules(min_evaluations=0, window=3, improvement=0.2, max_evaluations=10_000),
    StopRules(threshold=0.05, min_evaluations=10**6, max_evaluations=10_000),
    StopRules(min_evaluations=10**6, max_evaluations=95),
])
def test_first_stop_replays_the_rules_on_a_longer_run(rules):
    """The rules read only the history, so replayed on a longer run of the same seed they
    stop where a run under them stopped (bench/table1.py relies on it)."""
    fn = NoisyFlat(amplitude=0.01) if rules.threshold is None else Sphere(centre=0.4)
    ruled = CmaOptimizer(8, seed=5, popsize=10, rules=rules)
    reason = drive(ruled, fn)
    assert reason in ("slow_convergence", "threshold", "max_evaluations")
    free = CmaOptimizer(8, seed=5, popsize=10,
                        rules=StopRules(min_evaluations=10**6, max_evaluations=10**6))
    drive(free, fn, max_gens=ruled.iterations + 20)
    assert free.history[:ruled.iterations] == ruled.history
    assert rules.first_stop(free.history) == (ruled.iterations - 1, reason)
    assert rules.first_stop([asdict(h) for h in free.history]) == (ruled.iterations - 1,
                                                                       reason)
    assert rules.first_stop(free.history[:ruled.iterations - 1]) is None


def test_max_evaluations_cap():
    rules = StopRules(min_evaluations=10_000, max_evaluations=95)
    opt = CmaOptimizer(8, seed=3, popsize=10, rules=rules)
    assert drive(opt, Sphere(offset=1.0)) == "max_evaluations"
    assert opt.evaluations == 100


def test_cma_own_termination_is_reported():
    rules = StopRules(min_evaluations=10**6, max_evaluations=100_000)
    opt = CmaOptimizer(2, seed=4, rules=rules)
    reason = drive(opt, Sphere(centre=0.5))
    assert reason is not None and reason.startswith("cma:")


def test_from_config(make_spec):
    spec = make_spec(threshold=1.1, min_evaluations=300, window=20, max_evaluations=900)
    r = StopRules.from_config(spec.optimize)
    assert r == StopRules(1.1, 300, 20, 0.05, 900)


def test_same_seed_same_run_and_global_rng_untouched():
    np.random.seed(12345)
    before = np.random.get_state()
    runs = []
    for _ in range(2):
        opt = CmaOptimizer(8, seed=7, rules=StopRules(max_evaluations=200))
        drive(opt, Sphere())
        runs.append(opt)
    after = np.random.get_state()
    assert before[0] == after[0] and np.array_equal(before[1], after[1]) and before[2:] == after[2:]
    a, b = runs
    assert a.history == b.history
    np.testing.assert_array_equal(a.best_x, b.best_x)
    c = CmaOptimizer(8, seed=8, rules=StopRules(max_evaluations=200))
    drive(c, Sphere())
    assert c.history != a.history


def test_bounds_respected_and_x0_warm_start():
    opt = CmaOptimizer(5, seed=1, x0=np.full(5, 0.99), sigma0=0.5)
    for _ in range(5):
        xs = opt.ask()
        assert all(np.all((x >= 0.0) & (x <= 1.0)) for x in xs)
        opt.tell(xs, [float(np.sum(x)) for x in xs])


def test_nonfinite_objectives_rank_worst():
    opt = CmaOptimizer(3, seed=1)
    xs = opt.ask()
    fs = [np.nan] + [float(i) for i in range(1, len(xs))]
    fs[1] = np.inf
    stats = opt.tell(xs, fs)
    assert np.isfinite(stats.worst) and stats.best == 2.0
    np.testing.assert_array_equal(opt.best_x, xs[2])


@pytest.mark.parametrize("k", [0, 3, 7])
def test_dumps_loads_resumes_bit_identically(k):
    rules = StopRules(max_evaluations=150)
    fn = Sphere(centre=0.2)
    ref = CmaOptimizer(6, seed=11, rules=rules)
    reason_ref = drive(ref, fn)

    part = CmaOptimizer(6, seed=11, rules=rules)
    drive(part, fn, max_gens=k)
    blob = part.dumps()
    del part
    resumed = CmaOptimizer.loads(blob)
    assert resumed.iterations == k
    reason = drive(resumed, fn)
    assert reason == reason_ref
    assert resumed.history == ref.history
    np.testing.assert_array_equal(resumed.best_x, ref.best_x)
    assert resumed.best_f == ref.best_f
    # and the next asked generation is identical too
    for x, y in zip(resumed.ask(), ref.ask(), strict=True):
        np.testing.assert_array_equal(x, y)


def test_loads_rejects_garbage():
    with pytest.raises(CheckpointError):
        CmaOptimizer.loads(b"not a pickle")


def test_generation_stats_dict_round_trip():
    s = GenerationStats(3, 30, 1.0, 2.0, 3.0, 0.1, 0.9)
    assert GenerationStats.from_dict(asdict(s)) == s
