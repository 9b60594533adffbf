"""The paper's Table 1 against this product: wall-time bounds, what the optimiser needs, stop rules.

    .venv/bin/python bench/table1.py run SPEC [--seed 1] [--workers 2] [--max-evaluations M]
                                         [--out results/table1/NAME.json]
    .venv/bin/python bench/table1.py speeds [--seconds 3] [--out results/table1/speeds.json]
    .venv/bin/python bench/table1.py table [--dir results/table1] [--json]

`run` is `cmrt optimize SPEC --seed S --workers W` (the same CMA-ES, rules, candidates and
results bit for bit; `--max-evaluations` only truncates it: a capped run is a prefix of the
uncapped one) with a log of every generation written after each: its cumulative wall and CPU
seconds and every candidate's objective, fall, task success and simulated seconds. No final
re-evaluation. The machine's load average is logged at the start and the end.

`speeds` measures, in one process, raw ODE stepping and the full controller (CPU seconds per
simulated second, `sim.bench.run_task_bench`) for each Table 1 task's world.

`table` prints, per Table 1 row, from `speeds.json` and the logs found in `--dir`:
  * the targets (a tenth and a twentieth of the paper's time C);
  * lower bounds on wall time on 2 cores: evaluations x clip seconds x raw-ODE CPU per
    simulated second / 2, i.e. a zero-cost controller and perfect parallelism, at the paper's
    N read two ways: N evaluations (what C supports: the paper's runs were single threaded at
    ~0.5 CPU s per simulated second) and N iterations of our popsize (what issue 10 says);
  * from the seeded log: evaluations and wall seconds (and "idle": the simulated seconds of
    the generations up to it x the idle full-controller rate / 2 cores, no pool start-up or
    straggler time, so a lower estimate of an idle machine's wall) until the first candidate
    that stands
    and succeeds at its task, until the best is within 5 % and 1 % of the log's final best,
    and where scale-free stop rules (relative improvement over a window of generations) would
    have stopped, replayed exactly on the logged best-so-far (the rules read nothing else).
No assertions: an experiment (docs/benchmarks.md, "Table 1").
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from optim.objective import SimObjective
from optim.outcome import EvalOutcome

#: Cores of this machine (and of the paper's target: "2 workers").
CORES = 2
#: Raw-ODE stepping of the bench's world is measured for this long (simulated seconds).
SPEED_SECONDS = 3.0

#: Paper Table 1 (name, example spec, L s, delta, N, C s). The bends are the fast/slow bend.
TABLE1: tuple[tuple[str, str, float, float, int, float], ...] = (
    ("push dominoes", "examples/domino.yaml", 3.0, 0.6, 149, 328.0),
    ("catch ball", "examples/catch.yaml", 3.0, 0.9, 18, 40.0),
    ("slow bend", "examples/slow_bend.yaml", 2.6, 0.9, 328, 641.0),
    ("fast bend", "examples/fast_bend.yaml", 2.6, 1.1, 683, 1366.0),
    ("pull weight", "examples/sumo_pull.yaml", 3.0, 1.76, 121, 1179.0),
    ("hit tire", "examples/lion_hit.yaml", 6.0, 0.09, 471, 4948.0),
    ("dodge tire", "examples/lion_dodge.yaml", 4.0, 0.14, 459, 2460.0),
)
#: The lowest CPU seconds per simulated second measured on this machine idle (docs/
#: benchmarks.md, "On an idle machine, after every branch of the stop was merged", 14:55 UTC,
#: load 0.1-0.6; `cmrt bench --seconds 5`): (raw ODE, full controller) per world; the bends
#: are the humanoid without props (its quiet stance), the tire worlds the lion's stance. The
#: table uses the lower of these and the `speeds` run, so the bounds hold on an idle machine.
IDLE_CPU_PER_SIM_SECOND: dict[str, tuple[float, float]] = {
    "examples/domino.yaml": (0.0380, 0.0640),
    "examples/catch.yaml": (0.0316, 0.0557),
    "examples/slow_bend.yaml": (0.0304, 0.0456),
    "examples/fast_bend.yaml": (0.0304, 0.0456),
    "examples/sumo_pull.yaml": (0.061, 0.115),
    "examples/lion_hit.yaml": (0.085, 0.107),
    "examples/lion_dodge.yaml": (0.085, 0.107),
}
#: The paper's stated cost of its single-threaded C++ simulation (CPU s per simulated s).
PAPER_CPU_PER_SIM_SECOND = 0.5
#: Scale-free stop rules replayed on the logs: (window in generations, relative improvement,
#: minimum evaluations). The first is the paper's rule with "100 iterations" read as 100
#: evaluations (10 generations of 10); the spec default (100 generations, 700) for contrast.
REPLAYED_RULES: tuple[tuple[int, float, int], ...] = (
    (10, 0.05, 100), (10, 0.05, 200), (20, 0.05, 200), (10, 0.02, 200), (100, 0.05, 700))


@dataclass(frozen=True)
class TaskOutcome(EvalOutcome):
    """An `EvalOutcome` that also carries the task's own success (None: the task has none)."""

    task_success: bool | None = None


class RecordingObjective(SimObjective):
    """`SimObjective` whose outcome also says whether the task succeeded (same objective)."""

    def __call__(self, params: Any, stop_above: Any = None) -> EvalOutcome:
        ev = self.evaluation(params, stop_above=stop_above)
        return TaskOutcome(
            objective=float(ev.objective), fell=bool(ev.fell), cpu_seconds=float(ev.cpu_seconds),
            cut=bool(ev.cut), sim_seconds=float(ev.sim_seconds),
            task_success=None if ev.task_success is None else bool(ev.task_success))


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def run(args: argparse.Namespace) -> int:
    """A seeded optimisation of SPEC with a per-generation log (see the module docstring)."""
    from bench.table1 import RecordingObjective as Objective  # picklable by module name
    from optim.executors import make_executor
    from optim.loop import SearchSpace, new_optimizer, step
    from optim.run import BatchEvaluator
    from sim.spec import load_spec, parse_spec

    spec = load_spec(args.spec)
    if args.max_evaluations:
        data = spec.model_dump(mode="json")
        data["optimize"] = {**data["optimize"], "max_evaluations": args.max_evaluations}
        spec = parse_spec(data, args.spec)
    out = Path(args.out or f"results/table1/{Path(args.spec).stem}.log.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    log: dict[str, Any] = {"spec": args.spec, "name": spec.name, "seed": args.seed,
                           "workers": args.workers, "rules": spec.optimize.model_dump(),
                           "load_start": _load(), "generations": []}
    t0, c0 = time.perf_counter(), time.process_time()
    with make_executor(args.workers) as ex:
        space = SearchSpace.of(spec)
        opt = new_optimizer(spec, space, args.seed)
        log["popsize"] = opt.popsize
        evaluator = BatchEvaluator(ex, Objective(spec), opt.cut_margin)
        cpu = 0.0
        rule = opt.stop()
        while rule is None:
            res = step(opt, space, evaluator)
            cpu += sum(o.cpu_seconds for o in res.outcomes)
            log["generations"].append({
                "evaluations": res.stats.evaluations, "best_so_far": res.stats.best_so_far,
                "wall": time.perf_counter() - t0, "cpu": cpu + time.process_time() - c0,
                "load": os.getloadavg()[0],
                "candidates": [[o.objective, o.fell, getattr(o, "task_success", None),
                                o.sim_seconds, o.cut] for o in res.outcomes]})
            rule = opt.stop()
            log["stop_rule"], log["load_end"] = rule, _load()
            tmp = out.with_suffix(".tmp")
            tmp.write_text(json.dumps(log))
            tmp.replace(out)
            print(f"{spec.name}: {res.stats.evaluations} evaluations, best "
                  f"{res.stats.best_so_far:.4f}, {log['generations'][-1]['wall']:.0f} s, "
                  f"load {log['generations'][-1]['load']:.1f}", flush=True)
    print(f"stopped: {rule}; log {out}")
    return 0


def speeds(args: argparse.Namespace) -> int:
    """Raw ODE and full-controller CPU per simulated second of each Table 1 world."""
    from sim.bench import run_task_bench
    from sim.spec import load_spec

    rows = {"load_start": _load()}
    for _name, path, *_ in TABLE1:
        r = run_task_bench(load_spec(path), args.seconds)
        rows[path] = r
        print(json.dumps({path: r}), flush=True)
    rows["load_end"] = _load()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))
    return 0


def _first(gens: list[dict[str, Any]], pred: Any) -> dict[str, Any] | None:
    """The first generation (with the evaluations counted up to the candidate) where `pred`
    holds for a candidate: {"evaluations", "wall"} (wall at the generation's end)."""
    before = 0
    sim = 0.0
    for g in gens:
        sim += sum(c[3] for c in g["candidates"])
        for i, c in enumerate(g["candidates"]):
            if pred(c):
                return {"evaluations": before + i + 1, "wall": g["wall"], "value": c[0],
                        "generation_evaluations": g["evaluations"], "sim_seconds": sim}
        before = g["evaluations"]
    return None


def replay_rule(gens: list[dict[str, Any]], window: int, improvement: float,
                min_evaluations: int) -> dict[str, Any] | None:
    """Where the slow-convergence rule with these settings (no threshold, no cap) would have
    stopped the logged run (`optim.cmaes.StopRules.first_stop`: exact, the rule reads only the
    best so far and the evaluation count), None if it does not fire within the log."""
    from optim.cmaes import StopRules

    rules = StopRules(threshold=None, min_evaluations=min_evaluations, window=window,
                      improvement=improvement, max_evaluations=10**9)
    hit = rules.first_stop(gens)
    if hit is None:
        return None
    g = gens[hit[0]]
    sim = sum(c[3] for h in gens[:hit[0] + 1] for c in h["candidates"])
    return {"evaluations": g["evaluations"], "wall": g["wall"], "cpu": g["cpu"],
            "best": g["best_so_far"], "sim_seconds": sim}


def analyse_log(log: dict[str, Any]) -> dict[str, Any]:
    """Milestones of one seeded log (see the module docstring)."""
    gens = log["generations"]
    final = gens[-1]["best_so_far"]
    sims = [c[3] for g in gens for c in g["candidates"]]

    def within(frac: float) -> dict[str, Any] | None:
        return _first(gens, lambda c: c[0] <= final * (1.0 + frac))

    return {
        "name": log["name"], "seed": log["seed"], "popsize": log["popsize"],
        "evaluations": gens[-1]["evaluations"], "wall": gens[-1]["wall"],
        "cpu": gens[-1]["cpu"], "final_best": final, "stop_rule": log.get("stop_rule"),
        "load": f"{log['load_start']} -> {log.get('load_end')}",
        "mean_sim_seconds": sum(sims) / len(sims),
        "cpu_per_evaluation": gens[-1]["cpu"] / gens[-1]["evaluations"],
        "first_standing": _first(gens, lambda c: not c[1]),
        "first_success": _first(gens, lambda c: not c[1] and c[2] is not False),
        "within_5pc": within(0.05), "within_1pc": within(0.01),
        "rules": {f"w{w} {imp:g} min{m}": replay_rule(gens, w, imp, m)
                  for w, imp, m in REPLAYED_RULES},
        "paper_delta_reached": _first(gens, lambda c: c[0] <= log["rules"]["threshold"])
        if log["rules"].get("threshold") else None,
    }


def replay_best(log: dict[str, Any]) -> Any:
    """The best candidate's full parameters of a logged run, recovered without simulating:
    CMA-ES asks the same candidates again when told the logged values (its own RNG, seeded)."""
    from optim.loop import SearchSpace, new_optimizer
    from sim.spec import load_spec, parse_spec

    spec = load_spec(log["spec"])
    data = spec.model_dump(mode="json")
    data["optimize"] = {**data["optimize"], **log["rules"]}
    spec = parse_spec(data, log["spec"])
    space = SearchSpace.of(spec)
    opt = new_optimizer(spec, space, log["seed"])
    for g in log["generations"]:
        xs = opt.ask()
        opt.tell(xs, [c[0] for c in g["candidates"]])
    assert opt.best_f == log["generations"][-1]["best_so_far"], "the replay left the log"
    return spec, space.to_full(opt.best_x)


def windows(args: argparse.Namespace) -> int:
    """Sum of e^2 by phase for the flat spline and each log's best CMRT (one clip each)."""
    from bench.error_windows import phase_sums
    from optim.objective import evaluate_params

    out = {}
    for p in sorted(Path(args.dir).glob("*.log.json")):
        log = json.loads(p.read_text())
        spec, params = replay_best(log)
        row = {}
        for label, x in (("flat", None), ("best", params)):
            ev = evaluate_params(spec, x, traces=True)
            row[label] = {"objective": ev.objective, "fell": ev.fell,
                          "task_success": ev.task_success, "task_penalty": ev.task_penalty,
                          **phase_sums(spec, ev.traces)}
        row["delta"] = spec.optimize.threshold
        out[log["name"]] = row
        print(json.dumps({log["name"]: row}), flush=True)
    Path(args.dir, "windows.json").write_text(json.dumps(out, indent=1))
    return 0


def popsize_of(path: str) -> int:
    """The CMA-ES population of `cmrt optimize` for this spec (pycma's default for its
    dimension, 4 + floor(3 ln d), unless the spec sets one)."""
    import math

    from sim.spec import load_spec

    spec = load_spec(path)
    if spec.optimize.popsize:
        return int(spec.optimize.popsize)
    return 4 + int(3 * math.log(spec.cmrt_dimension))


def table(args: argparse.Namespace) -> int:
    """Print the bound table and each log's milestones."""
    d = Path(args.dir)
    sp = json.loads((d / "speeds.json").read_text()) if (d / "speeds.json").exists() else {}
    rows = []
    for name, path, length, delta, n, c in TABLE1:
        r: dict[str, Any] = {"task": name, "spec": path, "L": length, "delta": delta, "N": n,
                             "C": c, "tenth": c / 10, "twentieth": c / 20,
                             "paper_cpu_per_sim_s": c / (n * length)}
        s = sp.get(path)
        if s:
            idle_raw, idle_full = IDLE_CPU_PER_SIM_SECOND.get(path, (float("inf"),) * 2)
            raw = min(s["raw_ode_cpu_per_sim_second"], idle_raw)
            full = min(s["controller_cpu_per_sim_second"], idle_full)
            pop = popsize_of(path)
            r.update(raw=raw, full=full, popsize=pop,
                     measured=(s["raw_ode_cpu_per_sim_second"],
                               s["controller_cpu_per_sim_second"]))
            for key, evals in (("n_evals", n), ("n_gens", n * pop)):
                r[f"bound_{key}"] = evals * length * raw / CORES
                r[f"full_{key}"] = evals * length * full / CORES
        logp = d / f"{Path(path).stem}.log.json"
        if logp.exists():
            r["log"] = analyse_log(json.loads(logp.read_text()))
        rows.append(r)
    if args.json:
        print(json.dumps({"speeds_load": [sp.get("load_start"), sp.get("load_end")],
                          "rows": rows}, indent=1))
        return 0
    print(f"CPU seconds per simulated second: the lower of this machine's idle figures and "
          f"the `speeds` run (load {sp.get('load_start')} -> {sp.get('load_end')})")
    print("| task | N, C (s) | C/(N L) | C/10, C/20 | raw ODE, full | lower bound N evals "
          "(full ctrl) | popsize | lower bound N x popsize evals (full ctrl) | verdict |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "raw" not in r:
            continue
        b1, b2 = r["bound_n_evals"], r["bound_n_gens"]
        verdict = ("N x popsize: C/10 and C/20 impossible" if b2 > r["tenth"] else
                   "N x popsize: C/20 impossible" if b2 > r["twentieth"] else
                   "not excluded")
        print(f"| {r['task']} | {r['N']}, {r['C']:g} | {r['paper_cpu_per_sim_s']:.2f} | "
              f"{r['tenth']:.1f}, {r['twentieth']:.1f} | {r['raw']:.4f}, {r['full']:.4f} | "
              f"{b1:.1f} ({r['full_n_evals']:.1f}) | {r['popsize']} | "
              f"{b2:.1f} ({r['full_n_gens']:.1f}) | "
              f"{verdict} |")
    print()
    for r in rows:
        lg = r.get("log")
        if not lg:
            continue

        full = r.get("full")

        def f(m: dict[str, Any] | None, full: float | None = full) -> str:
            if m is None:
                return "not in log"
            idle = "" if full is None else f", idle {m['sim_seconds'] * full / CORES:.1f} s"
            return f"{m['evaluations']} ev, {m['wall']:.0f} s{idle}"

        print(f"{r['task']} ({lg['name']}, seed {lg['seed']}, load {lg['load']}): "
              f"{lg['evaluations']} evaluations in {lg['wall']:.0f} s wall, {lg['cpu']:.0f} s "
              f"CPU ({lg['cpu_per_evaluation']:.3f} per evaluation, {lg['mean_sim_seconds']:.2f}"
              f" simulated s each), best {lg['final_best']:.4f} ({lg['stop_rule']})")
        print(f"  first standing {f(lg['first_standing'])}; standing + task success "
              f"{f(lg['first_success'])}; within 5 % {f(lg['within_5pc'])}; within 1 % "
              f"{f(lg['within_1pc'])}; paper delta {r['delta']} reached: "
              f"{f(lg['paper_delta_reached'])}")
        for k, m in lg["rules"].items():
            print(f"  rule {k}: " + ("does not fire in the log" if m is None else
                  f"{f(m)}, best {m['best']:.4f} "
                  f"(+{100 * (m['best'] / lg['final_best'] - 1):.1f} % over the log's)"))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    pr = sub.add_parser("run")
    pr.add_argument("spec")
    pr.add_argument("--seed", type=int, default=1)
    pr.add_argument("--workers", type=int, default=2)
    pr.add_argument("--max-evaluations", type=int, default=None)
    pr.add_argument("--out", help="log file (default results/table1/<spec stem>.log.json)")
    ps = sub.add_parser("speeds")
    ps.add_argument("--seconds", type=float, default=SPEED_SECONDS)
    ps.add_argument("--out", default="results/table1/speeds.json")
    pw = sub.add_parser("windows")
    pw.add_argument("--dir", default="results/table1")
    pt = sub.add_parser("table")
    pt.add_argument("--dir", default="results/table1")
    pt.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    return {"run": run, "speeds": speeds, "windows": windows, "table": table}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
