"""The punching-bag scene measured: the hit, the bag's swing, and the outcome per bag mass.

    .venv/bin/python bench/punch_scene.py [SPEC] [--cmrt RESULT.json] [--mass 1 5 30 ...]
                                          [--no-handover] [--json]

For each bag mass (default: the spec's) and each CMRT (none, and the result's if given) it
simulates the clip and prints: fell / time / direction / reason, objective, whether a hand hit
the bag, the first hit's time and hand, the largest hand-bag contact force (N), the impulse
(N s) the character gave the bag in the task window, and the bag's largest swing (m).
`--no-handover` is a diagnostic: it lifts the controller's balance-lost rules (heel/toe lift,
inadmissible wrench time) so the clip runs on until a physical fall (a body on the ground, the
CM below 60 % of its height), to tell a rule's early call from a real tip-over. No assertions.
"""

from __future__ import annotations

import argparse
import json
import math

import sim.controllers.momentum as momentum
from optim.result import OptimizationResult
from sim.physics import DT, PROP_CHARACTER
from sim.rollout import Rollout
from sim.spec import load_spec, parse_spec
from sim.tasks.punch import BAG


def measure(spec, cmrt) -> dict:
    sim = Rollout(spec)
    task = sim.task
    t0, t1 = spec.clip.task_start, spec.clip.task_end
    impulse = [0.0]
    swing = [0.0]
    rest_x = task.bag.position[0]
    inner = task.after_step

    def after_step(physics, t):
        inner(physics, t)
        if t0 <= t <= t1 + 1e-9:
            for j, kind, a, _b, _p in physics.prop_contacts:
                if kind == PROP_CHARACTER and a == BAG:
                    impulse[0] += j.getFeedback()[0][0] * DT
        swing[0] = max(swing[0], abs(physics.prop(BAG).pose()[0] - rest_x))

    task.after_step = after_step
    try:
        ev = sim.run(cmrt)
    finally:
        sim.close()
    return {"mass": spec.task.mass, "fell": ev.fell, "fall_time": ev.fall_time,
            "fall_direction": ev.fall_direction, "fall_reason": ev.fall_reason,
            "objective": ev.objective, "hit": ev.task_success, "hit_time": task.hit_time,
            "hit_hand": task.hit_hand, "peak_force_n": task.peak_force,
            "impulse_n_s": impulse[0], "max_swing_m": swing[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("spec", nargs="?", default="examples/punch.yaml")
    ap.add_argument("--cmrt", help="a result file (cmrt optimize --out)")
    ap.add_argument("--mass", type=float, nargs="*", help="bag masses (kg) to simulate")
    ap.add_argument("--no-handover", action="store_true",
                    help="diagnostic: no balance-lost hand-over, run on to a physical fall")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.no_handover:
        momentum.FOOT_LIFT_LIMIT = math.inf
        momentum.WRENCH_VIOLATION_LIMIT = math.inf
    base = load_spec(args.spec)
    cmrts = [("none", None)]
    if args.cmrt:
        cmrts.append((args.cmrt, OptimizationResult.load(args.cmrt).spline()))
    rows = []
    for mass in args.mass or [base.task.mass]:
        data = base.model_dump()
        data["task"]["mass"] = mass
        spec = parse_spec(data, args.spec)
        for name, cmrt in cmrts:
            rows.append({"cmrt": name, **measure(spec, cmrt)})
    if args.json:
        print(json.dumps(rows))
        return 0
    for r in rows:
        fall = (f"fell {r['fall_time']:.3f} s {r['fall_direction']} ({r['fall_reason']})"
                if r["fell"] else "stands")
        hit = (f"hit {r['hit_time']:.3f} s {r['hit_hand']}, peak {r['peak_force_n']:.0f} N, "
               f"impulse {r['impulse_n_s']:.1f} N s" if r["hit"] else "missed")
        print(f"bag {r['mass']:5.1f} kg  cmrt {r['cmrt']:>16}: {fall:44s} objective "
              f"{r['objective']:8.4f}  {hit}; swing {r['max_swing_m']:.3f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
