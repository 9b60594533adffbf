"""Micro-benchmarks of the optim layer (no physics unless --sim): run with the project venv.

    .venv/bin/python bench/optim_bench.py [--json] [--sim SPEC] [--workers N]

Reports: CMRT spline scalar call (us), CMA-ES ask+tell overhead per generation (ms, d = 8),
checkpoint dump size (bytes) and time (ms), and with --sim the wall time per evaluation of the
spec's clip serially and through a PoolExecutor (evaluations per second).
"""

from __future__ import annotations

import argparse
import json
import time
import timeit

import numpy as np

from optim.cmaes import CmaOptimizer, StopRules
from optim.executors import PoolExecutor, SerialExecutor
from optim.spline import decode
from sim.spec import load_spec, parse_spec

GENERATIONS = 50
SPLINE_CALLS = 100_000


def bench_numerics() -> dict[str, float]:
    spec = parse_spec({"name": "b", "task": {"type": "quiet_stance"}, "clip": {"duration": 0.4}})
    s = decode(spec, np.random.default_rng(0).random(spec.cmrt_dimension))
    per_call = timeit.timeit(lambda: s(1.234), number=SPLINE_CALLS) / SPLINE_CALLS
    opt = CmaOptimizer(8, seed=1, rules=StopRules(max_evaluations=10**6))
    t0 = time.perf_counter()
    for _ in range(GENERATIONS):
        xs = opt.ask()
        opt.tell(xs, [float(np.sum(x**2)) for x in xs])
    per_gen = (time.perf_counter() - t0) / GENERATIONS
    t0 = time.perf_counter()
    blob = opt.dumps()
    dump_s = time.perf_counter() - t0
    return {
        "spline_call_us": per_call * 1e6,
        "cma_generation_ms": per_gen * 1e3,
        "checkpoint_bytes": float(len(blob)),
        "checkpoint_dump_ms": dump_s * 1e3,
    }


def bench_sim(spec_path: str, workers: int, n: int) -> dict[str, float]:
    from optim.objective import SimObjective

    spec = load_spec(spec_path)
    fn = SimObjective(spec)
    rng = np.random.default_rng(0)
    batch = [np.clip(0.5 + 0.1 * rng.standard_normal(spec.cmrt_dimension), 0, 1) for _ in range(n)]
    out: dict[str, float] = {}
    ex = SerialExecutor()
    ex.map(fn, batch[:1])  # build the simulator, JIT warm-up
    t0 = time.perf_counter()
    ex.map(fn, batch)
    out["serial_evals_per_s"] = n / (time.perf_counter() - t0)
    with PoolExecutor(workers) as pool:
        pool.map(fn, batch[:workers])  # warm-up in every worker
        t0 = time.perf_counter()
        pool.map(fn, batch)
        out[f"pool{workers}_evals_per_s"] = n / (time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--sim", metavar="SPEC", help="also time simulated evaluations of SPEC")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--evals", type=int, default=10)
    args = ap.parse_args()
    res = bench_numerics()
    if args.sim:
        res.update(bench_sim(args.sim, args.workers, args.evals))
    if args.json:
        print(json.dumps(res, indent=1))
    else:
        for k, v in res.items():
            print(f"{k:>24}: {v:.4g}")


if __name__ == "__main__":
    main()
