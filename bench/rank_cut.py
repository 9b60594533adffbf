"""The rank-preserving early stop (optim.rankcut) on a real optimisation: the same run with
and without it, compared generation by generation, and the simulated seconds it saves.

    python bench/rank_cut.py examples/fast_bend.yaml --workers 2 --seed 1   # `make run`'s run

Prints, for each run: wall seconds, simulated seconds of all evaluations, cut evaluations;
then whether every generation's mean, sigma, covariance, candidates, best and median, the
stop rule and the result are identical (bit for bit), and the simulated seconds saved.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import asdict

from optim.executors import PoolExecutor, SerialExecutor
from optim.loop import SearchSpace, final_evaluation, new_optimizer, run_generations
from optim.objective import SimObjective
from optim.run import BatchEvaluator
from sim import load_spec


class _Record:
    def __init__(self) -> None:
        self.rows: list[dict] = []

    def restore(self):  # noqa: ANN201
        return None

    def save(self, opt, generation, stats, candidates, wall_seconds) -> None:  # noqa: ANN001
        d = asdict(stats)
        d.pop("worst")
        self.rows.append({"stats": d, "mean": opt.mean.tobytes(), "sigma": opt.sigma,
                          "C": opt.covariance.tobytes(),
                          "x": [c.tobytes() for c in candidates]})


class _Counting(BatchEvaluator):
    def __init__(self, *a, **k) -> None:  # noqa: ANN002, ANN003
        super().__init__(*a, **k)
        self.outs: dict[int, list] = {}

    def evaluate(self, generation, candidates):  # noqa: ANN001, ANN201
        outs = super().evaluate(generation, candidates)
        self.outs[generation] = outs
        return outs


def run(spec, workers: int, seed: int, cut: bool) -> dict:  # noqa: ANN001
    space = SearchSpace.of(spec)
    opt = new_optimizer(spec, space, seed)
    with SerialExecutor() if workers == 1 else PoolExecutor(workers) as ex:
        ev = _Counting(ex, SimObjective(spec), opt.cut_margin if cut else None)
        ex.map(SimObjective(spec), [space.start])  # start the pool outside the timing
        rec = _Record()
        t0 = time.perf_counter()
        cpu0 = os.times()
        stop = run_generations(opt, space, ev, rec)
        final = final_evaluation(opt, space, ev)
        wall = time.perf_counter() - t0
    cpu1 = os.times()  # the pool's workers have ended: their CPU is counted (with start-up)
    outs = [o for g in sorted(ev.outs) for o in ev.outs[g]]
    return {"rows": rec.rows, "stop": stop, "best": final.best.objective,
            "winner": final.winner, "params": final.best_params.tobytes(), "outs": ev.outs,
            "wall": wall, "sim": sum(o.sim_seconds for o in outs),
            "cpu_children": (cpu1.children_user + cpu1.children_system)
            - (cpu0.children_user + cpu0.children_system),
            "cuts": sum(o.cut for o in outs), "evaluations": opt.evaluations}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-evaluations", type=int, default=None)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    spec = load_spec(a.spec)
    if a.max_evaluations:
        spec = spec.model_copy(update={"optimize": spec.optimize.model_copy(
            update={"max_evaluations": a.max_evaluations})})
    off = run(spec, a.workers, a.seed, cut=False)
    on = run(spec, a.workers, a.seed, cut=True)
    saved = 0.0
    for g, outs in on["outs"].items():
        for o, o_full in zip(outs, off["outs"][g], strict=True):
            if o.cut:
                saved += o_full.sim_seconds - o.sim_seconds
    same = all(off[k] == on[k] for k in ("rows", "stop", "best", "winner", "params"))
    out = {
        "spec": spec.name, "workers": a.workers, "seed": a.seed,
        "evaluations": on["evaluations"], "identical": same,
        "wall_s": {"no_cut": round(off["wall"], 2), "cut": round(on["wall"], 2)},
        "worker_cpu_s": {"no_cut": round(off["cpu_children"], 2),
                         "cut": round(on["cpu_children"], 2)},
        "sim_s": {"no_cut": round(off["sim"], 3), "cut": round(on["sim"], 3)},
        "cut_evaluations": on["cuts"], "sim_s_saved": round(saved, 3),
        "saved_fraction": round(saved / off["sim"], 4) if off["sim"] else 0.0,
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }
    print(json.dumps(out) if a.json else "\n".join(f"{k:>16}: {v}" for k, v in out.items()))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
