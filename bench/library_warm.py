"""What a job started from the library saves: evaluations to the same objective, warm against
cold, at values a family left out.

    .venv/bin/python bench/library_warm.py results/families/domino.json [--at 30 60 90 110 150]
        [--workers 2] [--sigma 0.05] [--json]

The family is a `cmrt family run` report (its `.runs` folder beside it holds every run). At each
value of --at (default: the family's leave-out values), the start a new job there gets from
the library (`POST /jobs` with `start: "library"`, application.library.library_start): the CMRT
interpolated between the neighbouring members, the member at that value left out (at an end of
the range, the nearest member's optimum), searched with CMA-ES step LIBRARY_WARM_SIGMA0 in the
full space, under the family's main rules and seed. It is compared with the family's cold
full-space run at that value (the flat spline, the same rules and seed): evaluations until
each first reached the cold run's final objective, until each was within 1 % of its own final
best, and the final objectives.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from application.library import LIBRARY_WARM_SIGMA0
from optim.executors import PoolExecutor
from optim.family import (
    converged_at,
    evaluations_to_reach,
    family_members,
    interpolated_params,
    member_spec,
    parse_family,
    plan_runs,
    reference_run_id,
)
from optim.family_run import load_finished
from optim.result import OptimizationResult
from optim.run import optimize


@dataclass
class _Run:
    """What the comparison reads of a finished run: its objective, evaluations and history."""

    objective: float
    evaluations: int
    history: list[dict[str, float]]


def _from_report(fs: Any, report: dict[str, Any]) -> tuple[dict[float, Any], dict[str, _Run]]:
    """The members (as results, for the interpolation) and every run's convergence curve, from
    a family report alone."""
    members = {}
    for m in report["members"]:
        spec = member_spec(fs, m["value"])
        members[float(m["value"])] = OptimizationResult.build(
            spec, m["params"], objective=m["objective"],
            baseline_objective=m["baseline_objective"])
    colds = {r["id"]: _Run(r["objective"], r["evaluations"],
                           [{"evaluations": e, "best_so_far": b} for e, b in r["curve"]])
             for r in report["runs"]}
    return members, colds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("family", help="a `cmrt family run` report (F.json; F.runs beside it is "
                                   "used when present)")
    ap.add_argument("--at", type=float, nargs="+", help="values (default: the leave-out ones)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sigma", type=float, default=LIBRARY_WARM_SIGMA0,
                    help=f"the warm start's CMA-ES step (default {LIBRARY_WARM_SIGMA0}, the "
                         "library start's)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    path = Path(args.family)
    report = json.loads(path.read_text())
    fs = parse_family(report["spec"])
    runs = plan_runs(fs)
    members, colds = _from_report(fs, report)
    if path.with_suffix(".runs").is_dir():  # the runs themselves, when they are kept
        results, _ = load_finished(path.with_suffix(".runs"), runs)
        members = {v: res for v, (_, res) in family_members(runs, results).items()}
    rows = []
    with PoolExecutor(args.workers) as pool:
        for v in args.at or fs.leave_out:
            v = float(v)
            cold = colds.get(reference_run_id(fs, runs, v))
            if cold is None:
                print(f"{v:g}: no cold run in the family; skipped")
                continue
            others = {u: r for u, r in members.items() if u != v}
            got = interpolated_params(fs, members, v)  # from the members other than v
            if got is not None:
                x0, lo, hi = got
                start = f"interpolated {lo:g}-{hi:g}"
            else:
                near = min(others, key=lambda u: (abs(u - v), u))
                x0, start = np.asarray(others[near].params, dtype=float), f"member {near:g}"
            spec = member_spec(fs, v)
            warm_spec = spec.model_copy(update={"optimize": spec.optimize.model_copy(
                update={"sigma0": args.sigma})})
            t0 = time.perf_counter()
            warm = optimize(warm_spec, pool, seed=fs.seed, x0=x0, cut=False)
            rows.append({
                "value": v, "start": start,
                "cold_objective": cold.objective, "warm_objective": warm.objective,
                "cold_evaluations": cold.evaluations, "warm_evaluations": warm.evaluations,
                "cold_to_cold_objective": evaluations_to_reach(cold.history, cold.objective),
                "warm_to_cold_objective": evaluations_to_reach(warm.history, cold.objective),
                "cold_converged_at": converged_at(cold.history),
                "warm_converged_at": converged_at(warm.history),
                "warm_wall_seconds": time.perf_counter() - t0,
            })
    with open("/proc/loadavg") as f:
        load = " ".join(f.read().split()[:3])
    if args.json:
        print(json.dumps({"load": load, "rows": rows}, indent=1))
        return 0
    leaf = fs.leaf
    print(f"| {leaf} | warm start | cold: objective (evals to it; to 1 %) | warm: objective "
          "(evals to the cold objective; to 1 %) | saving to the cold objective |")
    print("|---|---|---|---|---|")
    for r in rows:
        reach = r["warm_to_cold_objective"]
        saving = "-" if reach is None else f"{r['cold_to_cold_objective'] / max(reach, 1):.1f}x"
        print(f"| {r['value']:g} | {r['start']} | {r['cold_objective']:.3f} "
              f"({r['cold_to_cold_objective']}; {r['cold_converged_at']}) | "
              f"{r['warm_objective']:.3f} ({'never' if reach is None else reach}; "
              f"{r['warm_converged_at']}) | {saving} |")
    print(f"load average {load}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
