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

With --continuation up|down the family is a chain, as `bench/bend_family.py --continuation`
does for the bends and the paper did for its families ("previous optimization results as
starting points"): the masses in increasing (up) or decreasing (down) order, the first from the
flat spline under the main rules, each next one warm-started from the previous mass's optimum
with a small initial step (--warm-sigma) and its own short rules (--warm-window generations at
--warm-improvement, at most --warm-max-evaluations; no minimum), so neighbours stay on one
branch of optima and each member is cheap. The chain is then the family for steps 2 and 3
(--continuation both: an up and a down chain over every mass, the same files as up and down,
and the family keeps at each mass the better of the two optima);
the full-space references of step 2 are separate flat-start runs at the left-out masses under
the main rules (files full_m*.json), because the chain's members started from a neighbour's
optimum and their cost says nothing about a cold full-space search. Step 2 then reports three
speed-ups in evaluations (the paper's is time; a clip costs about the same CPU for every
candidate of one scene, so evaluations are the proxy): to the slow-convergence rule's
convergence point (the generation --window generations before the rule fired, after which
the best never again improved by --improvement: the paper's "convergence iterations", which
are below its 100-iteration window), to the stopping rule, to "equal quality" (evaluations
until each run's best first reached the worse of the two final objectives) and to within 1 %
of each run's own final best, and their medians. --reduced-start flat starts the reduced run
from the flat spline projected into the basis box, i.e. from the full-space run's start.
--basis-from all adds every flat-start full-space run saved in --out at another mass (the
other rows' references) to the chain's members in each row's basis; --basis-from best keeps
at each mass the better of the chain's member and the flat-start run saved there. --only
family / reduced stops before the reduced runs / before running missing full-space
references (so that these can run in another process into the same --out).
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

from optim.cmaes import StopRules  # noqa: E402
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


def member_spec(mass: float, args: argparse.Namespace, warm: bool = False) -> TaskSpec:
    """The template with task.mass = `mass` and the family's stopping rules (no threshold);
    `warm`: the continuation members' rules and initial step (--warm-*)."""
    data = yaml.safe_load(args.template.read_text())
    family = data.get("family") or "domino"
    data["name"] = f"{family}_m{mass:g}"
    data["family"] = family
    data["task"]["mass"] = float(mass)
    if warm:
        data["optimize"] = {
            "min_evaluations": 0,
            "window": args.warm_window,
            "improvement": args.warm_improvement,
            "max_evaluations": args.warm_max_evaluations,
            "sigma0": args.warm_sigma,
        }
    else:
        data["optimize"] = {  # no threshold: run to the slow-convergence rule
            "min_evaluations": args.min_evaluations,
            "window": args.window,
            "improvement": args.improvement,
            "max_evaluations": args.max_evaluations,
        }
    return parse_spec(data, f"domino family mass = {mass:g} kg")


def evaluations_to_reach(result: OptimizationResult, target: float) -> int | None:
    """Evaluations until the run's best-so-far first was <= target (None if never)."""
    for h in result.history:
        if h["best_so_far"] <= target:
            return int(h["evaluations"])
    return None


def evaluations_to_rule_convergence(result: OptimizationResult, window: int) -> int:
    """Evaluations at the slow-convergence rule's convergence point: the generation `window`
    generations before the one where the rule fired, after which the best never improved by
    the rule's margin again (the paper's Table 2 "convergence iterations": its reduced runs'
    32-163 are below its 100-iteration window, so they cannot count the window itself). A run
    stopped by another rule (the cap) has not converged: its whole count."""
    if result.stop_rule != "slow_convergence" or len(result.history) <= window:
        return int(result.evaluations)
    return int(result.history[-1 - window]["evaluations"])


def replay(result: OptimizationResult, rules: StopRules) -> tuple[int, float, int]:
    """Where `rules` would have stopped this run (they read only the best so far and the
    evaluation count, so the search up to there is the same): (evaluations at the stop, best
    objective there, evaluations at the slow-convergence rule's convergence point)."""
    hit = rules.first_stop(result.history)
    if hit is None:  # the rules do not fire within the run: it is the run as made
        return (int(result.evaluations), float(result.history[-1]["best_so_far"]),
                int(result.evaluations))
    i, rule = hit
    h = result.history
    converged = h[i - rules.window]["evaluations"] if rule == "slow_convergence" else \
        h[i]["evaluations"]
    return int(h[i]["evaluations"]), float(h[i]["best_so_far"]), int(converged)


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
    p.add_argument("--improvement", type=float, default=0.05)
    p.add_argument("--max-evaluations", type=int, default=300)
    p.add_argument("--continuation", choices=["up", "down", "updown", "both"],
                   help="optimise the family as a chain: masses in increasing (up) or "
                        "decreasing (down) order, the first from the flat spline under the "
                        "main rules, each next one warm-started from the previous optimum "
                        "under the --warm-* rules (files cont<dir>_s<S>_m*.json); updown: "
                        "an up chain over the masses <= --split and a down chain over the "
                        "rest, from the flat spline at the lightest and the heaviest mass; "
                        "both: an up and a down chain over every mass, the family keeping "
                        "at each mass the better of the two optima")
    p.add_argument("--split", type=float, default=90.0,
                   help="with --continuation updown: the heaviest mass of the up chain (kg)")
    p.add_argument("--warm-sigma", type=float, default=0.05)
    p.add_argument("--warm-window", type=int, default=5)
    p.add_argument("--warm-improvement", type=float, default=0.01)
    p.add_argument("--warm-max-evaluations", type=int, default=100)
    p.add_argument("--reduced-start", choices=["centre", "flat"], default="centre",
                   help="reduced-space start: the box centre (about the family mean) or the "
                        "flat spline projected into the box (the full-space run's start)")
    p.add_argument("--basis-from", choices=["family", "all", "best"], default="family",
                   help="PCA members: the family (every --masses member but the left-out "
                        "mass); all: the family and every flat-start full-space run saved "
                        "in --out (full_m*.json: the other rows' references) at another mass; "
                        "best: at each of --masses the better of the family member and the "
                        "saved flat-start run (also the family interpolated from)")
    p.add_argument("--replay-window", type=int, nargs="*", default=[],
                   help="also report each PCA row under the slow-convergence rule with these "
                        "windows (generations, shorter than --window), replayed exactly on "
                        "the saved histories (optim.cmaes.StopRules.first_stop)")
    p.add_argument("--template", type=Path, default=TEMPLATE)
    p.add_argument("--skip-full", action="store_true",
                   help="do not optimise missing members: use only those saved in --out")
    p.add_argument("--only", choices=["family", "reduced"], default=None,
                   help="stop after the family (and interpolation) / after the reduced runs, "
                        "before the full-space references that are missing")
    p.add_argument("--no-run", action="store_true",
                   help="optimise nothing: report what is saved in --out, the rest as missing")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if args.no_run:
        args.skip_full = True
    args.out.mkdir(parents=True, exist_ok=True)
    log = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else (
        lambda *a: print(*a, flush=True))
    report: dict = {"settings": {k: v for k, v in vars(args).items()
                                 if k not in ("out", "template", "json")},
                    "members": [], "pca": [], "replay": [], "interpolation": [],
                    "missing": []}

    def path(mass: float) -> Path:
        return args.out / f"full_m{mass:g}.json"

    def member_row(r: OptimizationResult, mass: float, start: str) -> dict:
        return {"mass": mass, "start": start, "flat": r.baseline_objective,
                "optimised": r.objective, "fell": r.fell, "evaluations": r.evaluations,
                "converged_at": evaluations_to_converge(r), "stop_rule": r.stop_rule,
                "wall_seconds": r.wall_seconds, "params": [round(x, 6) for x in r.params]}

    with PoolExecutor(args.workers) as pool:
        t_start = time.perf_counter()
        # flat-start full-space runs: every member (no continuation), or the chain's first
        # member and, later, the PCA references at the left-out masses (continuation)
        flat: dict[float, OptimizationResult] = {}
        family: dict[float, OptimizationResult] = {}
        source: dict[float, str] = {}  # where each family member came from
        prefix = f"cont{args.continuation}_s{args.warm_sigma:g}_"
        if args.continuation == "updown":  # two chains that can run in two processes
            chains = [("up", sorted(m for m in args.masses if m <= args.split)),
                      ("down", sorted((m for m in args.masses if m > args.split),
                                      reverse=True))]
        elif args.continuation == "both":  # two chains over every mass, each from its end
            chains = [("up", sorted(args.masses)), ("down", sorted(args.masses, reverse=True))]
        elif args.continuation:
            chains = [(args.continuation,
                       sorted(args.masses, reverse=args.continuation == "down"))]
        else:
            chains = []
        for direction, chain in chains:
            chain_prefix = f"cont{direction}_s{args.warm_sigma:g}_"
            prev, prev_m = None, 0.0
            for mass in chain:
                file = path(mass) if prev is None else args.out / f"{chain_prefix}m{mass:g}.json"
                if args.no_run and not file.exists():
                    report["missing"].append(f"member {mass:g}")
                    break  # the rest of the chain descends from this member
                if prev is None:
                    log(f"[{time.perf_counter() - t_start:.0f} s] full space (flat start), "
                        f"mass {mass:g} kg")
                    res = flat[mass] = run_or_load(
                        path(mass), member_spec(mass, args), pool, args.seed, log=log)
                    start = "flat"
                else:
                    log(f"[{time.perf_counter() - t_start:.0f} s] continuation from "
                        f"{prev_m:g} kg, mass {mass:g} kg")
                    res = run_or_load(
                        file, member_spec(mass, args, True),
                        pool, args.seed, x0=prev.params, log=log)
                    start = f"{prev_m:g} kg"
                # with two chains over one mass (both) the family keeps the better optimum
                if mass not in family or res.objective < family[mass].objective:
                    family[mass] = res
                    source[mass] = "flat" if prev is None else f"{direction} chain"
                report["members"].append(member_row(res, mass, start))
                prev, prev_m = res, mass
        if not args.continuation:
            neighbours = [m for v in args.interpolate for m in _around(args.masses, v)]
            for mass in run_order(args.masses, args.leave_out + args.interpolate + neighbours):
                if args.skip_full and not path(mass).exists():
                    report["missing"].append(mass)
                    continue
                log(f"[{time.perf_counter() - t_start:.0f} s] full space, mass {mass:g} kg")
                flat[mass] = family[mass] = run_or_load(path(mass), member_spec(mass, args),
                                                        pool, args.seed, log=log)
            for mass in sorted(family):
                report["members"].append(member_row(family[mass], mass, "flat"))

        if args.basis_from == "best":  # each mass's best full-space optimum, any start
            for file in sorted(args.out.glob("full_m*.json")):
                r = OptimizationResult.load(file)
                m = float(r.spec["task"]["mass"])
                flat.setdefault(m, r)
                if m in args.masses and (m not in family
                                         or flat[m].objective < family[m].objective):
                    family[m] = flat[m]
                    source[m] = "flat"
        report["family"] = [{"mass": m, "objective": family[m].objective,
                             "source": source.get(m, "flat")} for m in sorted(family)]

        def reference(mass: float) -> OptimizationResult:
            """The best full-space CMRT optimised at `mass`, whichever start it came from."""
            runs = [r for r in (family.get(mass), flat.get(mass)) if r is not None]
            return min(runs, key=lambda r: r.objective)

        for mass in args.interpolate:
            samples = [family[m] for m in sorted(family) if m != mass]
            if mass not in family:
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
            opt = reference(mass).objective
            report["interpolation"].append({
                "mass": mass, "between": [interp.lower_value, interp.upper_value],
                "flat": out_flat.objective, "interpolated": out_i.objective,
                "interpolated_fell": out_i.fell,
                "optimised": opt, "excess": out_i.objective / opt - 1.0,
            })
        if args.only == "family":
            args.leave_out = []

        if args.basis_from == "all":  # the flat-start references saved so far join the basis
            for file in sorted(args.out.glob("full_m*.json")):
                r = OptimizationResult.load(file)
                flat.setdefault(float(r.spec["task"]["mass"]), r)
        reduced: dict[float, OptimizationResult] = {}
        for mass in args.leave_out:
            others = [family[m] for m in sorted(family) if m != mass]
            if args.basis_from == "all":
                others += [flat[m] for m in sorted(flat)
                           if m != mass and all(flat[m] is not r for r in others)]
            if len(others) < args.k + 1:
                report["missing"].append(f"pca {mass:g}")
                continue
            basis = build_basis(others, k=args.k)
            spec = member_spec(mass, args)
            tag = ("" if args.reduced_start == "centre" else "flat_") + (
                "" if args.basis_from == "family" else f"{args.basis_from}_")
            name = (f"reduced_{tag}k{args.k}_n{len(others)}_m{mass:g}.json"
                    if not args.continuation else
                    f"{prefix}reduced_{tag}k{args.k}_n{len(others)}_m{mass:g}.json")
            log(f"[{time.perf_counter() - t_start:.0f} s] reduced space (k = {args.k}, "
                f"{len(others)} members), mass {mass:g} kg")
            if args.no_run and not (args.out / name).exists():
                report["missing"].append(f"reduced {mass:g}")
                continue
            x0 = flat_params(spec) if args.reduced_start == "flat" else None
            reduced[mass] = run_or_load(args.out / name, spec, pool, args.seed, basis=basis,
                                        x0=x0, log=log)
            reduced[mass].variance_k = float(np.sum(basis.variance_explained[: args.k]))
            reduced[mass].n_members = len(others)

        for mass, red in reduced.items():
            if mass not in flat:
                if (args.only == "reduced" or args.skip_full) and not path(mass).exists():
                    report["missing"].append(f"full-space reference {mass:g}")
                    continue
                log(f"[{time.perf_counter() - t_start:.0f} s] full space (flat start, PCA "
                    f"reference), mass {mass:g} kg")
                flat[mass] = run_or_load(path(mass), member_spec(mass, args), pool,
                                         args.seed, log=log)
            fr = flat[mass]
            # "equal quality": the worse of the two final objectives, reached by both runs
            quality = max(fr.objective, red.objective)
            n_full_q = evaluations_to_reach(fr, quality)
            n_red_q = evaluations_to_reach(red, quality)
            n_full_r = evaluations_to_rule_convergence(fr, args.window)
            n_red_r = evaluations_to_rule_convergence(red, args.window)
            report["pca"].append({
                "mass": mass, "k": args.k, "members": red.n_members,
                "variance_explained_k": red.variance_k,
                "reduced": red.objective, "reduced_fell": red.fell,
                "reduced_stop_rule": red.stop_rule,
                "reduced_evaluations": red.evaluations,
                "reduced_converged_at": evaluations_to_converge(red),
                "reduced_to_quality": n_red_q,
                "reduced_rule_converged_at": n_red_r,
                "reduced_wall_seconds": red.wall_seconds,
                "full": fr.objective, "full_stop_rule": fr.stop_rule,
                "full_evaluations": fr.evaluations,
                "full_converged_at": evaluations_to_converge(fr),
                "full_to_quality": n_full_q,
                "full_rule_converged_at": n_full_r,
                "full_wall_seconds": fr.wall_seconds,
                "best_family_member": family[mass].objective if mass in family else None,
                "relative_error": red.objective / fr.objective - 1.0,
                "speedup_rule": fr.evaluations / red.evaluations,
                "speedup_converged": evaluations_to_converge(fr) / evaluations_to_converge(red),
                "speedup_quality": n_full_q / n_red_q,
                "speedup_rule_converged": n_full_r / n_red_r,
                "speedup_wall": fr.wall_seconds / red.wall_seconds,
            })
            for w in args.replay_window:
                rules = StopRules(min_evaluations=args.min_evaluations, window=w,
                                  improvement=args.improvement,
                                  max_evaluations=args.max_evaluations)
                (n_f, f_f, c_f), (n_r, f_r, c_r) = replay(fr, rules), replay(red, rules)
                report["replay"].append({
                    "mass": mass, "window": w, "full": replay_row(n_f, f_f, c_f),
                    "reduced": replay_row(n_r, f_r, c_r),
                    "relative_error": f_r / f_f - 1.0, "speedup_stop": n_f / n_r,
                    "speedup_rule_converged": c_f / c_r})

    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    _print_tables(report)
    return 0


def replay_row(evaluations: int, objective: float, converged: int) -> dict:
    """One run's figures under a replayed rule."""
    return {"evaluations": evaluations, "objective": objective, "converged_at": converged}


def _around(masses: list[float], value: float) -> list[float]:
    """The nearest masses below and above `value` (value itself excluded)."""
    lo = [m for m in masses if m < value]
    hi = [m for m in masses if m > value]
    return ([max(lo)] if lo else []) + ([min(hi)] if hi else [])


def _print_tables(report: dict) -> None:
    print("\n| mass (kg) | start | no CMRT | optimised | evaluations (converged at) | "
          "stop rule | wall (s) |")
    print("|---|---|---|---|---|---|---|")
    for m in report["members"]:
        print(f"| {m['mass']:g} | {m['start']} | {m['flat']:.3f} | {m['optimised']:.3f}"
              f"{' (fell)' if m['fell'] else ''} | {m['evaluations']} ({m['converged_at']}) | "
              f"{m['stop_rule']} | {m['wall_seconds']:.0f} |")
    print("\nfamily: " + ", ".join(f"{f['mass']:g} kg {f['objective']:.3f} ({f['source']})"
                                   for f in report.get("family", [])))
    print("\n| mass (kg) | var. expl. (k, members) | reduced: obj (evals, stop, rule conv. at, "
          "1 % conv. at) | full: obj (evals, stop, rule conv. at, 1 % conv. at) | rel. error | "
          "speed-up: rule convergence / stop / equal quality / 1 % | paper: rel. error, "
          "speed-up |")
    print("|---|---|---|---|---|---|---|")
    for r in report["pca"]:
        paper = PAPER_TABLE_2.get(int(r["mass"]))
        ptxt = f"{paper[5]:+.1f} %, {paper[4]:.2f}x" if paper else "-"
        print(f"| {r['mass']:g} | {r['variance_explained_k']:.1%} ({r['k']}, "
              f"{r['members']}) | {r['reduced']:.3f}{' (fell)' if r['reduced_fell'] else ''}"
              f" ({r['reduced_evaluations']}, {r.get('reduced_stop_rule', '')}, "
              f"{r['reduced_rule_converged_at']}, {r['reduced_converged_at']}) | "
              f"{r['full']:.3f} ({r['full_evaluations']}, {r.get('full_stop_rule', '')}, "
              f"{r['full_rule_converged_at']}, {r['full_converged_at']}) | "
              f"{r['relative_error']:+.1%} | {r['speedup_rule_converged']:.2f}x / "
              f"{r['speedup_rule']:.2f}x / "
              f"{r.get('speedup_quality', float('nan')):.2f}x / "
              f"{r['speedup_converged']:.2f}x | {ptxt} |")
    if report["pca"]:
        def median(key: str) -> float:
            return float(np.median([r[key] for r in report["pca"]]))
        print(f"\nmedian speed-up: rule convergence {median('speedup_rule_converged'):.2f}x, "
              f"stop {median('speedup_rule'):.2f}x, equal quality "
              f"{median('speedup_quality'):.2f}x, 1 % {median('speedup_converged'):.2f}x; "
              f"worst relative error {max(r['relative_error'] for r in report['pca']):+.1%}")
    if report["replay"]:
        print("\n| mass (kg) | window (generations) | reduced: obj (evals, rule conv. at) | "
              "full: obj (evals, rule conv. at) | rel. error | speed-up: rule convergence / "
              "stop |")
        print("|---|---|---|---|---|---|")
        for r in report["replay"]:
            red, full = r["reduced"], r["full"]
            print(f"| {r['mass']:g} | {r['window']} | {red['objective']:.3f} "
                  f"({red['evaluations']}, {red['converged_at']}) | {full['objective']:.3f} "
                  f"({full['evaluations']}, {full['converged_at']}) | "
                  f"{r['relative_error']:+.1%} | {r['speedup_rule_converged']:.2f}x / "
                  f"{r['speedup_stop']:.2f}x |")
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
