"""Where a clip's CP error is: the sum of squared error by phase, with and without a CMRT.

    .venv/bin/python bench/error_windows.py SPEC [--cmrt RESULT.json] [--json]

The objective is sqrt(sum over steps of e^2), e = CP - support centre (metres). This splits
the sum into the clip's phases (preparation, task, the first 0.4 s of decay, the rest) for the
flat spline (no anticipation) and, given a result, for its CMRT. It also prints the ceiling
of what a CMRT can do while it leaves the task window's error as it is: sqrt(task-window sum of
the flat spline), against half the flat objective. If the ceiling is above the half, halving
needs the CMRT to cut the task window's own error (docs/physics.md). No assertions.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from sim.rollout import evaluate
from sim.spec import load_spec

EARLY_DECAY_S = 0.4  # s, the decay's first part, where the bend's transient settles


def phase_sums(spec, traces) -> dict[str, float]:
    """Sum of e^2 (m^2) by phase, each phase the steps with t in (start, end]: preparation,
    task, early_decay (the decay's first EARLY_DECAY_S), late_decay."""
    t, e = traces.t, np.nan_to_num(traces.error)
    t0, t1 = spec.clip.task_start, spec.clip.task_start + spec.clip.duration
    edges = {"preparation": (0.0, t0), "task": (t0, t1),
             "early_decay": (t1, t1 + EARLY_DECAY_S), "late_decay": (t1 + EARLY_DECAY_S, 1e9)}
    return {k: float((e[(t > a) & (t <= b)] ** 2).sum()) for k, (a, b) in edges.items()}


def windows(spec, cmrt) -> dict[str, float]:
    ev = evaluate(spec, cmrt, traces=True)
    out = phase_sums(spec, ev.traces)
    out["objective"] = ev.objective
    out["fell"] = ev.fell
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("spec")
    p.add_argument("--cmrt", help="an optimisation result (cmrt optimize --out)")
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    spec = load_spec(a.spec)
    rows = {"flat": windows(spec, None)}
    if a.cmrt:
        from optim.result import OptimizationResult

        rows["cmrt"] = windows(spec, OptimizationResult.load(a.cmrt).spline())
    flat = rows["flat"]
    summary = {"half_flat": 0.5 * flat["objective"],
               "ceiling_task_unchanged": math.sqrt(flat["task"])}
    if a.json:
        print(json.dumps({"windows": rows, **summary}, indent=2))
        return 0
    print(f"{'':6s} {'objective':>9s} {'prep':>7s} {'task':>7s} {'decay<0.4':>9s} "
          f"{'rest':>7s}  (sums of e^2, m^2)")
    for name, r in rows.items():
        print(f"{name:6s} {r['objective']:9.4f} {r['preparation']:7.3f} {r['task']:7.3f} "
              f"{r['early_decay']:9.3f} {r['late_decay']:7.3f}" + ("  FELL" if r["fell"] else ""))
    print(f"half the flat objective: {summary['half_flat']:.4f}; a CMRT that leaves the task "
          f"window's error unchanged scores at least {summary['ceiling_task_unchanged']:.4f}")
    if "cmrt" in rows:
        need = (0.5 * flat["objective"]) ** 2 - sum(
            v for k, v in rows["cmrt"].items() if k in ("preparation", "early_decay",
                                                         "late_decay"))
        print(f"to halve with this CMRT's other phases, the task window's sum must fall from "
              f"{rows['cmrt']['task']:.3f} to {max(need, 0.0):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
