"""SimObjective against the real simulator."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from optim import objective as objective_mod
from optim.objective import SPECS, SimObjective, evaluate_params
from optim.spline import flat_params
from sim.spec import canonical_spec, parse_spec, text_spec


@pytest.fixture(scope="module")
def tiny():
    return parse_spec(
        {
            "name": "tiny",
            "task": {"type": "quiet_stance"},
            "clip": {"preparation": 0.2, "duration": 0.1, "decay": 0.2},
        }
    )


def test_pickles_as_hash_and_text_and_caches_one_simulator(tiny):
    SPECS.clear()
    f = SimObjective(tiny)
    canonical = canonical_spec(tiny)
    g = pickle.loads(pickle.dumps(f))
    assert g == f and g.__getstate__() == {"spec_hash": canonical.hash,
                                           "spec_json": canonical.text}
    a = f(flat_params(tiny))
    sim_first = SPECS.simulator(f.canonical())
    b = g(flat_params(tiny))
    assert SPECS.simulator(g.canonical()) is sim_first and len(SPECS) == 1
    assert a.objective == b.objective and not a.fell and a.error is None


def test_one_cache_parses_a_spec_once_and_bounds_its_simulators(tiny):
    """A spec met in a process by its hash (a pickled objective, a stored job) is parsed on the
    first miss only; the cache keeps the simulators of the most recently used specs."""
    SPECS.clear()
    canonical = canonical_spec(tiny)
    parsed = []

    def load():
        parsed.append(1)
        return text_spec(canonical.text, canonical.hash)

    for _ in range(3):
        assert SPECS.get(canonical.hash, load).spec == tiny
    assert len(parsed) == 1
    cache = objective_mod.SpecCache(size=3, simulators=1)
    specs = [canonical_spec(tiny.model_copy(update={"name": f"tiny{i}"})) for i in range(4)]
    sims = [cache.simulator(c) for c in specs[:2]]
    assert sims[0] is not sims[1] and cache.simulator(specs[1]) is sims[1]
    assert cache.simulator(specs[0]) is not sims[0]  # its simulator was dropped, its spec kept
    assert specs[0].hash in cache
    for c in specs[2:]:
        cache.put(c)
    assert specs[1].hash not in cache and len(cache) == 3  # least recently used spec dropped


def test_flat_spline_equals_no_cmrt_and_is_deterministic(tiny):
    f = SimObjective(tiny)
    p = np.random.default_rng(0).random(tiny.cmrt_dimension)
    first = f(p)
    assert f(flat_params(tiny)).objective == f(None).objective
    assert f(p).objective == first.objective  # reset between runs


def test_evaluate_params_with_traces(tiny):
    ev = evaluate_params(tiny, flat_params(tiny), traces=True)
    assert ev.traces is not None and len(ev.traces.t) == ev.steps
    assert ev.objective == SimObjective(tiny)(None).objective


def test_optimize_end_to_end_on_real_simulator(tiny):
    from optim.executors import SerialExecutor
    from optim.run import optimize

    spec = tiny.model_copy(
        update={"optimize": tiny.optimize.model_copy(update={"max_evaluations": 6, "popsize": 6})}
    )
    res = optimize(spec, SerialExecutor(), seed=1)
    assert res.stop_rule == "max_evaluations" and res.evaluations == 6
    assert res.baseline_objective == SimObjective(tiny)(None).objective
    assert res.objective == min(h["best"] for h in res.history)


def test_serial_and_pool_optimize_a_real_bend_identically():
    """The same seed gives the same result whatever the executor and its worker count, on
    real simulations (a short bend: candidates differ, some may fall)."""
    from optim.executors import PoolExecutor, SerialExecutor
    from optim.run import optimize

    spec = parse_spec({
        "name": "short_bend", "family": "bend",
        "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.3},
        "task": {"type": "pose_change",
                 "target": {"waist": -40, "shoulder_r": 40, "shoulder_l": 40}},
        "optimize": {"max_evaluations": 30},
    })
    serial = optimize(spec, SerialExecutor(), seed=11).to_dict()
    assert serial["history"][0]["median"] != serial["history"][0]["best"]  # candidates differ
    for workers in (1, 2):
        with PoolExecutor(workers, timeout=120.0) as pool:
            pooled = optimize(spec, pool, seed=11).to_dict()
        for d in (serial, pooled):
            d.pop("wall_seconds", None)
        assert pooled == serial


def test_outcome_carries_the_fall_direction_and_the_task_verdict():
    """The domino without a CMRT falls backward and leaves the block standing: the objective's
    outcome says so (the evaluation rows and result files take these fields from it)."""
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[2]
    spec = parse_spec(yaml.safe_load((root / "examples/domino.yaml").read_text()))
    fn = SimObjective(spec)
    out = fn(flat_params(spec))
    ev = fn.evaluation(None)
    assert out.fell and out.fall_direction == "backward" == ev.fall_direction
    assert out.fall_time == ev.fall_time and 1.0 < out.fall_time < 2.0
    assert out.task_success is False and ev.task_success is False


def test_the_spec_cache_parses_once_when_threads_race(tiny):
    """The API's request threads and drivers share one cache: threads that miss the same spec
    at once parse it once between them, and evictions under concurrent use raise nothing."""
    import threading
    import time

    specs = [canonical_spec(tiny.model_copy(update={"name": f"t{i}"})) for i in range(6)]
    loads: list[str] = []
    errors: list[BaseException] = []

    def use(cache, k: int, rounds: int) -> None:
        def load(c):
            loads.append(c.hash)
            time.sleep(0.01)  # a parse takes milliseconds: the other threads miss meanwhile
            return c

        try:
            for n in range(rounds):
                c = specs[(k + n) % len(specs)]
                assert cache.get(c.hash, lambda c=c: load(c)).spec.name == c.spec.name
        except BaseException as err:  # noqa: BLE001 - reported below
            errors.append(err)

    for cache, rounds in ((objective_mod.SpecCache(), 6), (objective_mod.SpecCache(size=3), 12)):
        loads.clear()
        threads = [threading.Thread(target=use, args=(cache, k, rounds)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        if cache.size >= len(specs):
            assert sorted(loads) == sorted(c.hash for c in specs)  # once each
        assert len(cache) == min(cache.size, len(specs))
