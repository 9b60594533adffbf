"""The bend family (paper Figure 3 and Table 2's protocol): optimise, interpolate, reduce.

    .venv/bin/python bench/bend_family.py [--out results/bend_family] [--workers 2] [--seed 1]
        [--durations 0.4 0.6 0.8 1.0 1.2] [--between 0.5 0.7] [--leave-out 0.6 0.8 1.0] [--k 3]

Every member is the fast bend of `examples/fast_bend.yaml` (same pose, gain schedule and CMRT
settings) with task duration T and decay 1.6 - T, so the clip stays 2.6 s with a 1 s
preparation, as the paper's slow (T = 1.2) and fast (T = 0.4) bends. Optimisations run without
the early-exit threshold, to convergence (the paper's slow-convergence rule, 700 evaluations
minimum, or a cap of `--max-evaluations`), so that objectives are comparable.

1. Full-space CMA-ES for every T in --durations and --between (results saved as JSON in --out
   and reused when the script runs again, so a killed run loses only the optimisation in hand).
2. Interpolation (paper 4.2): for every T in --between, the CMRT interpolated from the
   --durations results only, simulated at T, against the CMRT optimised at T (target: within
   15 %).
3. PCA (Table 2's protocol): for every T in --leave-out, a basis of k components from the
   other --durations results (with --basis-from all: from every other optimised member,
   --between included, so that k = 3 components do not span the members trivially; with
   --basis-from runs: from every full-space result saved in --out, flat starts and every
   continuation run so far, several optima per T, as the paper's basis of 11 samples "collected
   in the test runs"; the reference is then the best of all those runs at T), a
   reduced-space optimisation of T under the same stopping rules, and the objective against
   the full-space one (target: within 5 %) and the speed-up in evaluations. Two speed-ups are
   printed: evaluations until the stopping rule fired (bounded below by the rule's
   700-evaluation minimum), and evaluations until the best reached within 1 % of that run's
   final best ("to converge"; the paper's itr columns are below its 100-iteration window, so
   they count convergence, not the rule).
With --continuation up|down the family used for 2. and 3. is optimised as the paper did for its
speed family ("previous optimization results as starting points"): T in increasing (up) or
decreasing (down) order, the first from the flat spline, each next one warm-started from the
previous T's result (files contup_*.json / contdown_*.json), so that neighbours tend to sit in
the same basin of the objective (the bend's objective has more than one, see
docs/benchmarks.md). The reference "optimised at T" is then the better of the flat-start and
the continued run at T, so warm starting can only make the comparison harder. --warm-sigma S
gives the warm-started runs a smaller initial step (files contup_sS_*.json): each member is then
a local refinement of the previous one, so the family stays on one branch of optima, which is
what linear interpolation between members assumes.
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

from optim.executors import PoolExecutor  # noqa: E402
from optim.interpolate import interpolate  # noqa: E402
from optim.objective import SimObjective  # noqa: E402
from optim.pca import build_basis  # noqa: E402
from optim.result import OptimizationResult  # noqa: E402
from optim.run import optimize  # noqa: E402
from optim.spline import flat_params  # noqa: E402
from sim.spec import TaskSpec, parse_spec  # noqa: E402

TEMPLATE = ROOT / "examples" / "fast_bend.yaml"
ACTIVE_SECONDS = 1.6  # s, task + decay: the clip stays preparation + 1.6 s for every T
CONVERGED_WITHIN = 0.01  # "converged" = best within 1 % of the run's final best


def member_spec(duration: float, max_evaluations: int, template: Path = TEMPLATE,
                sigma0: float | None = None) -> TaskSpec:
    data = yaml.safe_load(template.read_text())
    family = data.get("family") or "bend"
    data["name"] = f"{family}_T{duration:g}"
    data["family"] = family
    data["clip"] = {
        "preparation": data["clip"]["preparation"],
        "duration": duration,
        "decay": round(ACTIVE_SECONDS - duration, 6),
    }
    data["optimize"] = {"max_evaluations": max_evaluations}  # no threshold: run to convergence
    if sigma0 is not None:
        data["optimize"]["sigma0"] = sigma0
    return parse_spec(data, f"bend family T = {duration:g}")


def evaluations_to_converge(result: OptimizationResult) -> int:
    final = result.history[-1]["best_so_far"]
    for h in result.history:
        if h["best_so_far"] <= final * (1.0 + CONVERGED_WITHIN):
            return int(h["evaluations"])
    return int(result.evaluations)


def run_or_load(path: Path, spec: TaskSpec, pool: PoolExecutor, seed: int, basis=None,
                x0=None, log=print) -> OptimizationResult:
    if path.exists():
        return OptimizationResult.load(path)
    t0 = time.perf_counter()
    res = optimize(spec, pool, seed=seed, basis=basis, x0=x0,
                   checkpoint=path.with_suffix(".ckpt"), resume=True)
    res.save(path)
    path.with_suffix(".ckpt").unlink(missing_ok=True)
    log(f"  {path.name}: {res.objective:.4f} (flat {res.baseline_objective:.4f}), "
        f"{res.evaluations} evaluations, {res.stop_rule}, {time.perf_counter() - t0:.0f} s")
    return res


def stored_runs(out: Path) -> list[tuple[float, OptimizationResult]]:
    """(T, result) of every full-space optimisation saved in `out`: the flat-start members
    (full_T*.json) and every continuation (cont*_T*.json), reduced-space runs excluded."""
    found = []
    for path in sorted(out.glob("*.json")):
        if not (path.name.startswith(("full_T", "cont"))) or "reduced" in path.name:
            continue
        r = OptimizationResult.load(path)
        found.append((float(r.spec["clip"]["duration"]), r))
    return found


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "results" / "bend_family")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--durations", type=float, nargs="+", default=[0.4, 0.6, 0.8, 1.0, 1.2])
    p.add_argument("--between", type=float, nargs="*", default=[0.5, 0.7])
    p.add_argument("--leave-out", type=float, nargs="*", default=[0.6, 0.8, 1.0])
    p.add_argument("--k", type=int, default=3)
    p.add_argument("--basis-from", choices=["durations", "all", "runs"], default="durations",
                   help="PCA members: the --durations results, every optimised member "
                        "(--durations and --between), or every optimised result in --out "
                        "(all starts and continuations run so far: several optima per T); the "
                        "left-out T is never in its basis")
    p.add_argument("--max-evaluations", type=int, default=1500)
    p.add_argument("--continuation", choices=["up", "down"],
                   help="warm-start each T from the previous one (see module docstring)")
    p.add_argument("--warm-sigma", type=float, default=None, metavar="S",
                   help="with --continuation: CMA-ES sigma0 of the warm-started members "
                        "(default: the spec's, 0.2); a small S refines the previous member "
                        "locally, so the family follows one branch of optima")
    p.add_argument("--template", type=Path, default=TEMPLATE,
                   help="the spec every member copies but for its timing (default: the fast "
                        "bend; its schedule windows without start/end follow each member's task)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    report: dict = {"members": [], "interpolation": [], "pca": []}
    prefix = f"cont{args.continuation}_" if args.continuation else ""
    if args.continuation and args.warm_sigma is not None:
        prefix += f"s{args.warm_sigma:g}_"

    def member_row(r: OptimizationResult, T: float, start: str) -> dict:
        return {
            "T": T, "start": start, "flat": r.baseline_objective, "optimised": r.objective,
            "fell": r.fell, "evaluations": r.evaluations,
            "converged_at": evaluations_to_converge(r), "stop_rule": r.stop_rule,
            "wall_seconds": r.wall_seconds,
        }

    with PoolExecutor(args.workers) as pool:
        members = sorted(set(args.durations) | set(args.between))
        flat_start: dict[float, OptimizationResult] = {}
        for T in members:
            spec = member_spec(T, args.max_evaluations, args.template)
            flat_start[T] = run_or_load(args.out / f"full_T{T:g}.json", spec, pool, args.seed,
                                        log=log)
            report["members"].append(member_row(flat_start[T], T, "flat"))
        full = flat_start
        if args.continuation:
            full, prev, prev_T = {}, None, 0.0
            for T in sorted(members, reverse=args.continuation == "down"):
                spec = member_spec(T, args.max_evaluations, args.template, args.warm_sigma)
                if prev is None:  # the first member starts from the flat spline: that run
                    full[T] = flat_start[T]
                else:
                    full[T] = run_or_load(args.out / f"{prefix}T{T:g}.json", spec, pool,
                                          args.seed, x0=prev.params, log=log)
                report["members"].append(
                    member_row(full[T], T, "flat" if prev is None else f"T = {prev_T:g}"))
                prev, prev_T = full[T], T
        # the best result found at each T, whichever start it came from
        reference = {T: min((flat_start[T], full[T]), key=lambda r: r.objective)
                     for T in members}

        samples = [full[T] for T in args.durations]
        for T in args.between:
            spec = member_spec(T, args.max_evaluations, args.template)
            interp = interpolate(samples, T, key="duration")
            fn = SimObjective(spec)
            out_i, out_flat = pool.map(fn, [interp.params(spec), flat_params(spec)])
            opt = reference[T].objective
            report["interpolation"].append({
                "T": T, "between": [interp.lower_value, interp.upper_value],
                "flat": out_flat.objective, "interpolated": out_i.objective,
                "interpolated_fell": out_i.fell, "optimised": opt,
                "excess": out_i.objective / opt - 1.0,
            })

        runs = stored_runs(args.out) if args.basis_from == "runs" else []
        for T in args.leave_out:
            if args.basis_from == "runs":
                others = [r for d, r in runs if abs(d - T) > 1e-9]
                fr = min([reference[T]] + [r for d, r in runs if abs(d - T) <= 1e-9],
                         key=lambda r: r.objective)
            else:
                pool_T = args.durations if args.basis_from == "durations" else members
                others = [full[d] for d in pool_T if d != T]
                fr = reference[T]
            basis = build_basis(others, k=args.k)
            spec = member_spec(T, args.max_evaluations, args.template)
            tag = {"durations": "", "all": "all_", "runs": "runs_"}[args.basis_from]
            red = run_or_load(args.out / f"{prefix}reduced_k{args.k}_{tag}T{T:g}.json", spec,
                              pool, args.seed, basis=basis, log=log)
            report["pca"].append({
                "T": T, "k": args.k, "members": [m.name for m in others],
                "variance_explained_k": float(np.sum(basis.variance_explained[: args.k])),
                "reduced": red.objective, "reduced_fell": red.fell,
                "reduced_evaluations": red.evaluations,
                "reduced_converged_at": evaluations_to_converge(red),
                "full": fr.objective, "full_evaluations": fr.evaluations,
                "full_converged_at": evaluations_to_converge(fr),
                "relative_error": red.objective / fr.objective - 1.0,
                "speedup_rule": fr.evaluations / red.evaluations,
                "speedup_converged": evaluations_to_converge(fr) / evaluations_to_converge(red),
            })

    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    print("\n| T (s) | start | flat | optimised | evaluations (converged at) | stop rule | "
          "wall (s) |")
    print("|---|---|---|---|---|---|---|")
    for m in report["members"]:
        print(f"| {m['T']:g} | {m['start']} | {m['flat']:.4f} | {m['optimised']:.4f}"
              f"{' (fell)' if m['fell'] else ''} | {m['evaluations']} ({m['converged_at']}) | "
              f"{m['stop_rule']} | {m['wall_seconds']:.0f} |")
    print("\n| T (s) | from | flat | interpolated | optimised at T | excess (target <= 15 %) |")
    print("|---|---|---|---|---|---|")
    for r in report["interpolation"]:
        lo, hi = r["between"]
        print(f"| {r['T']:g} | {lo:g}, {hi:g} | {r['flat']:.4f} | {r['interpolated']:.4f}"
              f"{' (fell)' if r['interpolated_fell'] else ''} | {r['optimised']:.4f} | "
              f"{r['excess']:+.1%} |")
    print("\n| left out T (s) | k | var. explained | reduced (evals, converged at) | "
          "full (evals, converged at) | rel. error (target <= 5 %) | speed-up rule / converged |")
    print("|---|---|---|---|---|---|---|")
    for r in report["pca"]:
        print(f"| {r['T']:g} | {r['k']} | {r['variance_explained_k']:.1%} | {r['reduced']:.4f} "
              f"({r['reduced_evaluations']}, {r['reduced_converged_at']}) | {r['full']:.4f} "
              f"({r['full_evaluations']}, {r['full_converged_at']}) | "
              f"{r['relative_error']:+.1%} | {r['speedup_rule']:.2f}x / "
              f"{r['speedup_converged']:.2f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
