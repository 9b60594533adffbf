"""A lower bound on what any CMRT can do for a clip: CMA-ES on the task window's error alone.

    .venv/bin/python bench/task_window_bound.py SPEC [--knots N] [--seed S] [--workers 2]
        [--max-evaluations 1000] [--sigma0 0.2] [--max-displacement M] [--out RESULT.json] [--json]

The objective is sqrt(S), S = sum over the clip's steps of e^2 (e = CP - support centre,
metres), and S splits into the task window's part S_task and the rest. For every CMRT,
objective^2 >= S_task, so min over CMRTs of the objective >= sqrt(min over CMRTs of S_task).
This script searches for that minimum directly: CMA-ES (the optimiser of `cmrt optimize`, same
encoding, seed and stopping rules but no early-exit threshold) on sqrt(S_task) of the clip, a
fall scoring the simulator's fall penalty (so falling CMRTs rank last, as in `cmrt optimize`).
If the smallest task-window error it finds is above half the flat spline's objective, no CMRT
of this form can halve the objective (to the extent CMA-ES finds the minimum: the figure is
an upper estimate of the true minimum of S_task, so of the bound; its seed and evaluations are
printed). Prints the flat spline's objective and S_task, the best S_task found, the full
objective of that CMRT, and the verdict. No assertions (an experiment, docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from functools import lru_cache
from typing import Any

from bench.error_windows import phase_sums  # the same phases as the ceiling's
from optim.objective import SimObjective
from optim.outcome import EvalOutcome


def task_window_sum(spec: Any, evaluation: Any) -> float:
    """Sum of e^2 (m^2) over the steps inside the task window (start, end]."""
    return phase_sums(spec, evaluation.traces)["task"]


@lru_cache(maxsize=8)
def _spec(spec_json: str) -> Any:
    """The parsed spec, once per process (SimObjective keeps only its JSON)."""
    from sim.spec import parse_spec

    return parse_spec(json.loads(spec_json), "task window bound spec")


class TaskWindowObjective(SimObjective):
    """sqrt(task-window sum of e^2) of the clip; a fall scores the simulator's fall penalty."""

    def __call__(self, params: Any) -> EvalOutcome:
        ev = self.evaluation(params, traces=True)
        value = ev.objective if ev.fell else math.sqrt(task_window_sum(_spec(self.spec_json), ev))
        return EvalOutcome(objective=float(value), fell=bool(ev.fell),
                           cpu_seconds=float(ev.cpu_seconds))


def run(args: argparse.Namespace) -> dict[str, Any]:
    from bench.task_window_bound import TaskWindowObjective as Objective  # picklable by module name
    from optim.executors import make_executor
    from optim.run import optimize
    from sim.spec import load_spec, parse_spec

    spec = load_spec(args.spec)
    data = spec.model_dump(mode="json")
    data["optimize"] = {**data.get("optimize", {}), "threshold": None,
                        "max_evaluations": args.max_evaluations, "sigma0": args.sigma0}
    if args.knots:
        data["cmrt"] = {**data.get("cmrt", {}), "knots": args.knots}
    if args.max_displacement:
        data["cmrt"] = {**data.get("cmrt", {}), "max_displacement": args.max_displacement}
    spec = parse_spec(data, "task window bound spec")
    full = SimObjective(spec)
    flat_ev = full.evaluation(None, traces=True)
    with make_executor(args.workers) as ex:
        result = optimize(spec, ex, seed=args.seed, objective=Objective(spec))
    if args.out:
        result.save(args.out)
    flat_task = task_window_sum(spec, flat_ev)
    best = full.evaluation(result.params, traces=True)
    best_task = task_window_sum(spec, best)
    if best_task > flat_task:  # the flat spline is a CMRT too
        best, best_task = flat_ev, flat_task
    half = 0.5 * flat_ev.objective
    return {
        "spec": args.spec, "knots": spec.cmrt.knots, "seed": args.seed,
        "max_displacement": spec.cmrt.max_displacement, "sigma0": spec.optimize.sigma0,
        "evaluations": result.evaluations, "stop_rule": result.stop_rule,
        "flat_objective": flat_ev.objective, "flat_task_sum": flat_task,
        "half_flat": half,
        "best_task_sum": best_task, "bound": math.sqrt(best_task),
        "best_full_objective": best.objective, "best_fell": best.fell,
        "halving_possible": bool(math.sqrt(best_task) <= half),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("spec")
    p.add_argument("--knots", type=int, default=None, help="spline knots (default: the spec's)")
    p.add_argument("--max-displacement", type=float, default=None,
                   help="the spline's displacement bound in metres (default: the spec's)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--max-evaluations", type=int, default=1000)
    p.add_argument("--sigma0", type=float, default=0.2)
    p.add_argument("--out", help="save the CMA-ES result (its objective is the task window's)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    r = run(args)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(f"{r['spec']}: {r['knots']} knots, displacement <= {r['max_displacement']:g} m, "
          f"sigma0 {r['sigma0']:g}, seed {r['seed']}, {r['evaluations']} evaluations "
          f"({r['stop_rule']})")
    print(f"flat spline: objective {r['flat_objective']:.4f}, task-window sum "
          f"{r['flat_task_sum']:.3f} m^2; half the objective {r['half_flat']:.4f}")
    print(f"smallest task-window sum found {r['best_task_sum']:.3f} m^2 -> bound on any CMRT's "
          f"objective {r['bound']:.4f}, as good as the search (that CMRT's full objective "
          f"{r['best_full_objective']:.4f}{', falls' if r['best_fell'] else ''})")
    print("halving is " + ("not excluded" if r["halving_possible"] else
                           "out of reach of this CMRT form as far as this search found: the "
                           "bound is above half the flat"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
