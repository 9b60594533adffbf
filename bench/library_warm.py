"""What a job started from the library saves: evaluations to the same objective, warm against
cold, at values a family left out.

    .venv/bin/python bench/library_warm.py results/families/domino.json [--at 30 60 90 110 150]
        [--workers 2] [--sigma 0.05] [--json]

The family is a `cmrt family run` report. At each value of --at (default: the family's
leave-out values), the library holds the family's members but the one at that value
(application.library.import_family), and the job starts where `POST /jobs` with `start:
"library"` starts it (application.library.library_start): the CMRT interpolated between the
neighbouring members, or across a strategy switch the nearer member; at an end of the range
no start (the flat spline, as a cold job). It is searched with the start's CMA-ES step
(LIBRARY_WARM_SIGMA0; --sigma to compare others) in the full space, under the family's main
rules and seed. It is compared with the family's cold
full-space run at that value (the flat spline, the same rules and seed): evaluations until
each first reached the cold run's final objective, until each was within 1 % of its own final
best, and the final objectives.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from application.library import LIBRARY_WARM_SIGMA0, import_family, library_start
from optim.executors import PoolExecutor
from optim.family.checks import converged_at, evaluations_to_reach
from optim.family.plan import plan_runs, reference_run_id
from optim.family.spec import member_spec, parse_family
from optim.run import optimize
from store import open_repository


@dataclass
class _Run:
    """What the comparison reads of a finished run: its objective, evaluations and history."""

    objective: float
    evaluations: int
    history: list[dict[str, float]]


def _colds(report: dict[str, Any]) -> dict[str, _Run]:
    """Every run's objective, evaluations and convergence curve, from a family report."""
    return {r["id"]: _Run(r["objective"], r["evaluations"],
                          [{"evaluations": e, "best_so_far": b} for e, b in r["curve"]])
            for r in report["runs"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("family", help="a `cmrt family run` report")
    ap.add_argument("--at", type=float, nargs="+", help="values (default: the leave-out ones)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sigma", type=float,
                    help=f"the warm start's CMA-ES step (default: the library start's, "
                         f"{LIBRARY_WARM_SIGMA0})")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    path = Path(args.family)
    report = json.loads(path.read_text())
    fs = parse_family(report["spec"])
    runs = plan_runs(fs)
    colds = _colds(report)
    rows = []
    with PoolExecutor(args.workers) as pool:
        for v in args.at or fs.leave_out:
            v = float(v)
            cold = colds.get(reference_run_id(fs, runs, v))
            if cold is None:
                print(f"{v:g}: no cold run in the family; skipped")
                continue
            spec = member_spec(fs, v)
            with tempfile.TemporaryDirectory() as tmp:  # the library without the member at v
                repo = open_repository(f"sqlite:///{tmp}/library.db")
                import_family(repo, {**report, "members": [
                    m for m in report["members"] if abs(m["value"] - v) > 1e-9]})
                got = library_start(repo, spec)  # what POST /jobs starts this job from
                repo.engine.dispose()
            x0 = None if got is None else np.asarray(got["x0"], dtype=float)
            start = "cold (no library start)" if got is None else got["from"]
            sigma = args.sigma if args.sigma is not None else (
                spec.optimize.sigma0 if got is None else got["sigma0"])
            warm_spec = spec.model_copy(update={"optimize": spec.optimize.model_copy(
                update={"sigma0": sigma})})
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
