"""A family of one tire task along one of its parameters, by continuation, with a PCA basis and
an interpolation check (paper 4.2 and Table 2's protocol, on a CPU budget).

    .venv/bin/python bench/tire_family.py [--template examples/lion_hit.yaml]
        [--field tire.mass] [--key mass] [--values 24 28 32 36 40] [--start 32]
        [--max-evaluations 200] [--warm-max-evaluations 80] [--warm-sigma 0.1]
        [--min-evaluations 60] [--window 5] [--leave-out 28 36] [--k 2]
        [--reduced-max-evaluations 60] [--out results/tire_family] [--workers 2] [--seed 1]
        [--json]

Every member is the template with `task.<field>` set to the value (e.g. `tire.mass`: the
tire's mass; `launch.toward`: its speed); `--key` is the name of that field among the task's
parameters stored with a result (`TireConfig.parameters`: mass, speed, vertical, height), the
key interpolation reads. The optimisations run without the early-exit threshold (the
slow-convergence rule after --min-evaluations with a --window-generation window, or the cap).

1. Continuation (the paper's "previous optimization results as starting points"): the --start
   member from the flat spline (cap --max-evaluations), then outward along the values, each
   member warm-started from its optimised neighbour nearer the start, with CMA-ES sigma0
   --warm-sigma and cap --warm-max-evaluations, so that neighbours sit in one basin of
   optima, which linear interpolation between them assumes. Results are saved in --out as
   they finish and reused when the script runs again.
2. PCA: for every value in --leave-out, a k-component basis of the OTHER members' results and
   a reduced-space optimisation there (cap --reduced-max-evaluations), against the
   full-space one (relative error, evaluations).
3. Interpolation: for every interior member, the CMRT interpolated from its two neighbours
   (the member itself excluded), simulated at its value, against the one optimised there.
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

from optim.executors import PoolExecutor  # noqa: E402
from optim.interpolate import interpolate  # noqa: E402
from optim.pca import build_basis  # noqa: E402
from optim.result import OptimizationResult  # noqa: E402
from sim.rollout import evaluate  # noqa: E402
from sim.spec import TaskSpec, parse_spec  # noqa: E402

TEMPLATE = ROOT / "examples" / "lion_hit.yaml"


def member_spec(value: float, args: argparse.Namespace, warm: bool) -> TaskSpec:
    """The template with task.<field> = value, no threshold, the member's budget."""
    data = yaml.safe_load(args.template.read_text())
    family = data.get("family") or data["name"]
    data["name"] = f"{family}_{args.key}{value:g}"
    data["family"] = family
    node = data["task"]
    *parents, leaf = args.field.split(".")
    for p in parents:
        node = node.setdefault(p, {})
    node[leaf] = float(value)
    data["optimize"] = {
        "min_evaluations": args.min_evaluations, "window": args.window,
        "max_evaluations": args.warm_max_evaluations if warm else args.max_evaluations,
    }
    if warm and args.warm_sigma is not None:
        data["optimize"]["sigma0"] = args.warm_sigma
    return parse_spec(data, f"{family} family {args.field} = {value:g}")


def continuation_order(values: list[float], start: float) -> list[tuple[float, float | None]]:
    """(value, the neighbour it starts from or None) walking outward from `start`."""
    values = sorted(values)
    i0 = values.index(start)
    order: list[tuple[float, float | None]] = [(start, None)]
    order += [(values[i], values[i + 1]) for i in range(i0 - 1, -1, -1)]
    order += [(values[i], values[i - 1]) for i in range(i0 + 1, len(values))]
    return order


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--template", type=Path, default=TEMPLATE)
    p.add_argument("--field", default="tire.mass")
    p.add_argument("--key", default="mass")
    p.add_argument("--values", type=float, nargs="+", default=[24, 28, 32, 36, 40])
    p.add_argument("--start", type=float, default=32)
    p.add_argument("--max-evaluations", type=int, default=200)
    p.add_argument("--warm-max-evaluations", type=int, default=80)
    p.add_argument("--warm-sigma", type=float, default=0.1)
    p.add_argument("--min-evaluations", type=int, default=60)
    p.add_argument("--window", type=int, default=5)
    p.add_argument("--leave-out", type=float, nargs="*", default=[28, 36])
    p.add_argument("--k", type=int, default=2)
    p.add_argument("--reduced-max-evaluations", type=int, default=60)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "tire_family")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if args.start not in args.values:
        p.error("--start must be one of --values")
    args.out.mkdir(parents=True, exist_ok=True)
    log = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else (
        lambda *a: print(*a, flush=True))
    report: dict = {"settings": {k: (str(v) if isinstance(v, Path) else v)
                                 for k, v in vars(args).items() if k != "json"},
                    "members": [], "pca": [], "interpolation": []}
    t_start = time.perf_counter()
    with PoolExecutor(args.workers) as pool:
        full: dict[float, OptimizationResult] = {}
        for value, prev in continuation_order(args.values, args.start):
            log(f"[{time.perf_counter() - t_start:.0f} s] {args.key} {value:g} "
                f"(from {'flat' if prev is None else f'{prev:g}'})")
            spec = member_spec(value, args, warm=prev is not None)
            x0 = None if prev is None else full[prev].params
            full[value] = run_or_load(args.out / f"cont_{args.key}{value:g}.json", spec, pool,
                                      args.seed, x0=x0, log=log)
            r = full[value]
            report["members"].append({
                args.key: value, "start": "flat" if prev is None else prev,
                "flat": r.baseline_objective, "optimised": r.objective, "fell": r.fell,
                "evaluations": r.evaluations, "converged_at": evaluations_to_converge(r),
                "stop_rule": r.stop_rule, "wall_seconds": r.wall_seconds,
                "knot_times": r.knot_times, "values": r.values,
                "vertical_values": r.vertical_values})

        for value in args.leave_out:
            others = [full[v] for v in sorted(full) if v != value]
            basis = build_basis(others, k=args.k)
            log(f"[{time.perf_counter() - t_start:.0f} s] reduced space (k = {args.k}), "
                f"{args.key} {value:g}")
            data_args = argparse.Namespace(**{**vars(args),
                                              "max_evaluations": args.reduced_max_evaluations})
            red = run_or_load(args.out / f"reduced_k{args.k}_{args.key}{value:g}.json",
                              member_spec(value, data_args, warm=False), pool, args.seed,
                              basis=basis, log=log)
            fr = full[value]
            report["pca"].append({
                args.key: value, "k": args.k, "members": len(others),
                "variance_explained_k": float(np.sum(basis.variance_explained[: args.k])),
                "reduced": red.objective, "reduced_fell": red.fell,
                "reduced_evaluations": red.evaluations,
                "reduced_converged_at": evaluations_to_converge(red),
                "full": fr.objective, "full_evaluations": fr.evaluations,
                "relative_error": red.objective / fr.objective - 1.0})

        values = sorted(full)
        for value in values[1:-1]:
            samples = [full[v] for v in values if v != value]
            interp = interpolate(samples, value, key=args.key)
            spec = member_spec(value, args, warm=False)
            # In this process, not the pool: the task's success is read from the Evaluation.
            out_i, out_flat = evaluate(spec, interp.spline()), evaluate(spec)
            opt = full[value].objective
            report["interpolation"].append({
                args.key: value, "between": [interp.lower_value, interp.upper_value],
                "flat": out_flat.objective, "interpolated": out_i.objective,
                "interpolated_fell": out_i.fell, "interpolated_task_success":
                out_i.task_success, "optimised": opt, "excess": out_i.objective / opt - 1.0})
    report["wall_seconds"] = time.perf_counter() - t_start
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    key = args.key
    print(f"\n| {key} | start | no CMRT | optimised | fell | evaluations (within 1 % at) | "
          "stop rule | wall (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for m in report["members"]:
        print(f"| {m[key]:g} | {m['start']} | {m['flat']:.3f} | {m['optimised']:.3f} | "
              f"{m['fell']} | {m['evaluations']} ({m['converged_at']}) | {m['stop_rule']} | "
              f"{m['wall_seconds']:.0f} |")
    print(f"\n| {key} | k | variance (k) | reduced | evaluations | full | evaluations | "
          "error |")
    print("|---|---|---|---|---|---|---|---|")
    for r in report["pca"]:
        print(f"| {r[key]:g} | {r['k']} | {r['variance_explained_k']:.3f} | "
              f"{r['reduced']:.3f} | {r['reduced_evaluations']} | {r['full']:.3f} | "
              f"{r['full_evaluations']} | {100 * r['relative_error']:+.1f} % |")
    print(f"\n| {key} | between | no CMRT | interpolated | fell | task | optimised | excess |")
    print("|---|---|---|---|---|---|---|---|")
    for r in report["interpolation"]:
        print(f"| {r[key]:g} | {r['between'][0]:g}-{r['between'][1]:g} | {r['flat']:.3f} | "
              f"{r['interpolated']:.3f} | {r['interpolated_fell']} | "
              f"{r['interpolated_task_success']} | {r['optimised']:.3f} | "
              f"{100 * r['excess']:+.1f} % |")
    print(f"\nwall {report['wall_seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
