"""The domino family along the wall (block) mass: Table 2's protocol and interpolation.

    .venv/bin/python bench/domino_family.py [--out results/domino_family] [--workers 2]
        [--seed 1] [--masses 30 40 50 60 70 80 90 110 130 140 150]
        [--leave-out 30 60 90 110 150] [--interpolate 70 130] [--k 3]
        [--min-evaluations 150] [--window 10] [--max-evaluations 300] [--json]

Every member is `examples/domino.yaml` (same scene, push, gain schedule and CMRT settings) with
the block's `mass` changed. The optimisations run without the early-exit threshold (to the
slow-convergence rule: after --min-evaluations, stop when the best improved by less than 5 %
over the last --window generations; or --max-evaluations), identically for the full and the
reduced space, so that objectives and evaluation counts are comparable. The paper's window is
100 iterations after 700 evaluations; the defaults here are smaller because CPU is scarce
(say so next to the figures).

1. Full-space CMA-ES (flat start) for every mass in --masses, in the order given by
   `run_order` (the left-out masses and the interpolation references first). Each result is
   saved as JSON in --out as soon as it is finished (a checkpoint is kept while it runs) and
   is reused when the script runs again, so a killed run loses at most the generation in hand.
2. PCA (Table 2): for every mass in --leave-out, a k-component basis of the full-space
   results at every OTHER mass, a reduced-space optimisation of that mass (box centre start,
   same stopping rules), and its objective against the full-space one (relative error) and
   the speed-up in evaluations (to the stop rule, and to within 1 % of the run's final best).
3. Interpolation (paper 4.2) along the mass: for every mass in --interpolate, the CMRT
   interpolated from the nearest optimised masses on either side (the mass itself excluded),
   simulated at that mass, against the CMRT optimised there.
Steps 2 and 3 run for whatever members are available; missing ones are reported as missing.
Prints markdown tables (for docs/benchmarks.md); --json prints the raw numbers instead.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bend_family import evaluations_to_converge, run_or_load  # noqa: E402

from optim.errors import InterpolationError  # noqa: E402
from optim.executors import PoolExecutor  # noqa: E402
from optim.interpolate import interpolate  # noqa: E402
from optim.objective import SimObjective  # noqa: E402
from optim.pca import build_basis  # noqa: E402
from optim.result import OptimizationResult  # noqa: E402
from optim.spline import flat_params  # noqa: E402
from sim.spec import TaskSpec, parse_spec  # noqa: E402

TEMPLATE = ROOT / "examples" / "domino.yaml"
#: Paper Table 2 (domino, k = 3): mass kg -> (itr reduced, fv reduced, itr full, fv full,
#: speed-up, relative error %).
PAPER_TABLE_2 = {
    30: (71, 1.096, 143, 1.086, 2.01, 0.9),
    60: (56, 1.128, 270, 1.09, 4.82, 3.4),
    90: (32, 1.325, 231, 1.299, 7.21, 2.0),
    110: (113, 1.467, 451, 1.467, 3.99, 0.0),
    150: (163, 1.741, 309, 1.726, 1.89, 0.8),
}


def member_spec(mass: float, args: argparse.Namespace) -> TaskSpec:
    data = yaml.safe_load(args.template.read_text())
    family = data.get("family") or "domino"
    data["name"] = f"{family}_m{mass:g}"
    data["family"] = family
    data["task"]["mass"] = float(mass)
    data["optimize"] = {  # no threshold: run to the slow-convergence rule
        "min_evaluations": args.min_evaluations,
        "window": args.window,
        "max_evaluations": args.max_evaluations,
    }
    return parse_spec(data, f"domino family mass = {mass:g} kg")


def run_order(masses: list[float], first: list[float]) -> list[float]:
    """The masses to optimise, those in `first` (in their order) before the rest."""
    head = [m for m in first if m in masses]
    return list(dict.fromkeys(head + [m for m in masses if m not in head]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "results" / "domino_family")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--masses", type=float, nargs="+",
                   default=[30, 40, 50, 60, 70, 80, 90, 110, 130, 140, 150])
    p.add_argument("--leave-out", type=float, nargs="*", default=[30, 60, 90, 110, 150])
    p.add_argument("--interpolate", type=float, nargs="*", default=[70, 130])
    p.add_argument("--k", type=int, default=3)
    p.add_argument("--min-evaluations", type=int, default=150)
    p.add_argument("--window", type=int, default=10)
    p.add_argument("--max-evaluations", type=int, default=300)
    p.add_argument("--template", type=Path, default=TEMPLATE)
    p.add_argument("--skip-full", action="store_true",
                   help="do not optimise missing members: use only those saved in --out")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else (
        lambda *a: print(*a, flush=True))
    report: dict = {"settings": {k: v for k, v in vars(args).items()
                                 if k not in ("out", "template", "json")},
                    "members": [], "pca": [], "interpolation": [], "missing": []}

    def path(mass: float) -> Path:
        return args.out / f"full_m{mass:g}.json"

    with PoolExecutor(args.workers) as pool:
        full: dict[float, OptimizationResult] = {}
        t_start = time.perf_counter()
        neighbours = [m for v in args.interpolate for m in _around(args.masses, v)]
        for mass in run_order(args.masses, args.leave_out + args.interpolate + neighbours):
            if args.skip_full and not path(mass).exists():
                report["missing"].append(mass)
                continue
            log(f"[{time.perf_counter() - t_start:.0f} s] full space, mass {mass:g} kg")
            full[mass] = run_or_load(path(mass), member_spec(mass, args), pool, args.seed,
                                     log=log)
        for mass in sorted(full):
            r = full[mass]
            report["members"].append({
                "mass": mass, "flat": r.baseline_objective, "optimised": r.objective,
                "fell": r.fell, "evaluations": r.evaluations,
                "converged_at": evaluations_to_converge(r), "stop_rule": r.stop_rule,
                "wall_seconds": r.wall_seconds})

        for mass in args.leave_out:
            others = [full[m] for m in sorted(full) if m != mass]
            if mass not in full or len(others) < args.k + 1:
                report["missing"].append(f"pca {mass:g}")
                continue
            basis = build_basis(others, k=args.k)
            log(f"[{time.perf_counter() - t_start:.0f} s] reduced space (k = {args.k}, "
                f"{len(others)} members), mass {mass:g} kg")
            red = run_or_load(args.out / f"reduced_k{args.k}_n{len(others)}_m{mass:g}.json",
                              member_spec(mass, args), pool, args.seed, basis=basis, log=log)
            fr = full[mass]
            report["pca"].append({
                "mass": mass, "k": args.k, "members": len(others),
                "variance_explained_k": float(np.sum(basis.variance_explained[: args.k])),
                "reduced": red.objective, "reduced_fell": red.fell,
                "reduced_evaluations": red.evaluations,
                "reduced_converged_at": evaluations_to_converge(red),
                "reduced_wall_seconds": red.wall_seconds,
                "full": fr.objective, "full_evaluations": fr.evaluations,
                "full_converged_at": evaluations_to_converge(fr),
                "full_wall_seconds": fr.wall_seconds,
                "relative_error": red.objective / fr.objective - 1.0,
                "speedup_rule": fr.evaluations / red.evaluations,
                "speedup_converged": evaluations_to_converge(fr) / evaluations_to_converge(red),
                "speedup_wall": fr.wall_seconds / red.wall_seconds,
            })

        for mass in args.interpolate:
            samples = [full[m] for m in sorted(full) if m != mass]
            if mass not in full:
                report["missing"].append(f"interpolation {mass:g}")
                continue
            try:
                interp = interpolate(samples, mass, key="mass")
            except InterpolationError as err:
                report["missing"].append(f"interpolation {mass:g}: {err}")
                continue
            spec = member_spec(mass, args)
            out_i, out_flat = pool.map(SimObjective(spec), [interp.params(spec),
                                                            flat_params(spec)])
            opt = full[mass].objective
            report["interpolation"].append({
                "mass": mass, "between": [interp.lower_value, interp.upper_value],
                "flat": out_flat.objective, "interpolated": out_i.objective,
                "interpolated_fell": out_i.fell, "optimised": opt,
                "excess": out_i.objective / opt - 1.0,
            })

    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    _print_tables(report)
    return 0


def _around(masses: list[float], value: float) -> list[float]:
    """The nearest masses below and above `value` (value itself excluded)."""
    lo = [m for m in masses if m < value]
    hi = [m for m in masses if m > value]
    return ([max(lo)] if lo else []) + ([min(hi)] if hi else [])


def _print_tables(report: dict) -> None:
    print("\n| mass (kg) | no CMRT | optimised | evaluations (converged at) | stop rule | "
          "wall (s) |")
    print("|---|---|---|---|---|---|")
    for m in report["members"]:
        print(f"| {m['mass']:g} | {m['flat']:.3f} | {m['optimised']:.3f}"
              f"{' (fell)' if m['fell'] else ''} | {m['evaluations']} ({m['converged_at']}) | "
              f"{m['stop_rule']} | {m['wall_seconds']:.0f} |")
    print("\n| mass (kg) | var. expl. (k) | reduced: obj (evals, conv. at, wall s) | "
          "full: obj (evals, conv. at, wall s) | rel. error | speed-up rule / converged / "
          "wall | paper: rel. error, speed-up |")
    print("|---|---|---|---|---|---|---|")
    for r in report["pca"]:
        paper = PAPER_TABLE_2.get(int(r["mass"]))
        ptxt = f"{paper[5]:.1f} %, {paper[4]:.2f}x" if paper else "-"
        print(f"| {r['mass']:g} | {r['variance_explained_k']:.1%} ({r['k']}, "
              f"{r['members']} members) | {r['reduced']:.3f}"
              f"{' (fell)' if r['reduced_fell'] else ''}"
              f" ({r['reduced_evaluations']}, {r['reduced_converged_at']}, "
              f"{r['reduced_wall_seconds']:.0f}) | {r['full']:.3f} ({r['full_evaluations']}, "
              f"{r['full_converged_at']}, {r['full_wall_seconds']:.0f}) | "
              f"{r['relative_error']:+.1%} | {r['speedup_rule']:.2f}x / "
              f"{r['speedup_converged']:.2f}x / {r['speedup_wall']:.2f}x | {ptxt} |")
    print("\n| mass (kg) | from (kg) | no CMRT | interpolated | optimised there | "
          "excess (target <= 10 %) |")
    print("|---|---|---|---|---|---|")
    for r in report["interpolation"]:
        lo, hi = r["between"]
        print(f"| {r['mass']:g} | {lo:g}, {hi:g} | {r['flat']:.3f} | {r['interpolated']:.3f}"
              f"{' (fell)' if r['interpolated_fell'] else ''} | {r['optimised']:.3f} | "
              f"{r['excess']:+.1%} |")
    if report["missing"]:
        print(f"\nnot (yet) available: {', '.join(str(m) for m in report['missing'])}")


if __name__ == "__main__":
    sys.exit(main())
