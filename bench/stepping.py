"""Pushes near the CM with and without stepping (the stepping seed paper's Fig. 7 and 8).

    .venv/bin/python bench/stepping.py case --force 300 --duration 0.4 [--backward] [--stepping]
    .venv/bin/python bench/stepping.py grid --durations 0.1 0.2 0.4 --forces 100 700 50 \
        [--delay 0.2]

Every clip is built from a spec: the step controller's settings are the spec's controller-block
fields (`--delay`, `--fixed-gains`, `--params`; sim/controllers/config.py).

`case` prints one clip's outcome and, with stepping, the steps (detection, lift-off,
touch-down, length, the QP's planned CoP inside the support at every swing solve);
`grid` runs every force of a grid per duration and direction, with and without stepping, and
prints which survived (with stepping the survived set is not an interval: a bisection would
be wrong), the largest survived force, and the steps taken.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from sim.rollout import Rollout
from sim.spec import parse_spec

PUSH_START = 1.0  # s
DECAY = 2.5  # s after the push


def push_spec(force: float, duration: float, direction: str, body: str,
              controller: dict[str, Any]) -> dict:
    return {"name": "step_push", "clip": {"preparation": PUSH_START, "duration": duration,
                                          "decay": DECAY},
            "task": {"type": "push", "force": force, "direction": direction, "body": body},
            "controller": {"type": "momentum", **controller}}


def controller_block(stepping: bool, gains: dict | None = None,
                     settings: dict | None = None) -> dict[str, Any]:
    """The spec's controller block: without stepping `gains` are the momentum overrides; with
    it they are the feet-fixed phase's (`feet_fixed`) and `settings` the step controller's
    fields (`response_delay`, `max_steps`, ...)."""
    if not stepping:
        return {"stepping": False, **(gains or {})}
    block: dict[str, Any] = {"stepping": True, **(settings or {})}
    if gains is not None:
        block["feet_fixed"] = gains
    return block


def rollout(force: float, duration: float, direction: str, body: str,
            controller: dict[str, Any]) -> Rollout:
    """One push clip with this controller block."""
    return Rollout(parse_spec(push_spec(force, duration, direction, body, controller)))


def run_case(force: float, duration: float, direction: str, stepping: bool, body: str,
             settings: dict | None = None, traces: bool = False,
             gains: dict | None = None) -> tuple[dict, Any]:
    sim = rollout(force, duration, direction, body, controller_block(stepping, gains, settings))
    try:
        ev = sim.run(None, traces=traces)
    finally:
        sim.close()
    out = {"force": force, "duration": duration, "direction": direction, "stepping": stepping,
           "fell": ev.fell, "fall_time": ev.fall_time, "fall_reason": ev.fall_reason,
           "objective": ev.objective}
    if stepping:
        steps = []
        for r in sim.controller.steps:
            inside = [lo - 1e-9 <= cop <= hi + 1e-9 for _t, cop, lo, hi, _f in r.solves]
            steps.append({
                "detected": r.detected, "lift_off": r.start, "touchdown": r.touchdown,
                "direction": r.direction, "planned_land_x": r.plan.land[0],
                "planned_length": r.plan.land[0] - r.plan.start[0], "length": r.length,
                "capture_point_at_land": r.plan.capture_at_land,
                "solves": len(r.solves), "zmp_inside": sum(inside),
                "stance_lift": r.stance_lift,
                "ik_max_error": max((e for _t, e in r.ik_error), default=math.nan)})
        out["steps"] = steps
        out["phase"] = sim.controller.phase
    return out, ev


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("case")
    c.add_argument("--force", type=float, default=300.0)
    c.add_argument("--duration", type=float, default=0.4)
    c.add_argument("--backward", action="store_true")
    c.add_argument("--stepping", action="store_true")
    c.add_argument("--body", default="pelvis")
    g = sub.add_parser("grid")
    g.add_argument("--durations", type=float, nargs="+", default=[0.1, 0.2, 0.4])
    g.add_argument("--forces", type=float, nargs=3, default=[100.0, 700.0, 50.0],
                   metavar=("FIRST", "LAST", "STEP"))
    g.add_argument("--body", default="pelvis")
    g.add_argument("--modes", nargs="+", choices=("fixed", "stepping"),
                   default=["fixed", "stepping"], help="which controllers to run")
    for sp in (c, g):
        sp.add_argument("--delay", type=float, default=None,
                        help="the step controller's response_delay (s; default its own, 0)")
        sp.add_argument("--fixed-gains", default=None, metavar="JSON",
                        help="feet-fixed gains as JSON, e.g. "
                             '\'{"cop_box": 0.005, "d_l": 20}\': the spec\'s controller '
                             "overrides without stepping, its feet_fixed "
                             "with it")
        sp.add_argument("--params", default=None, metavar="JSON",
                        help="the step controller's spec fields as JSON, e.g. "
                             '\'{"max_steps": 3, "clearance": 0.08}\'')
    args = ap.parse_args()
    gains = json.loads(args.fixed_gains) if args.fixed_gains else None
    params = json.loads(args.params) if args.params else {}
    if args.delay is not None:
        params["response_delay"] = args.delay
    if args.cmd == "case":
        out, _ = run_case(args.force, args.duration, "backward" if args.backward else "forward",
                          args.stepping, args.body, params, gains=gains)
        print(json.dumps(out, indent=1))
        return
    first, last, step = args.forces
    forces = [first + k * step for k in range(int(round((last - first) / step)) + 1)]
    rows = []
    for dur in args.durations:
        for direction in ("forward", "backward"):
            for stepping in [m == "stepping" for m in args.modes]:
                survived, steps = [], {}
                for f in forces:
                    out, _ = run_case(f, dur, direction, stepping, args.body, params,
                                      gains=gains)
                    if not out["fell"]:
                        survived.append(f)
                        steps[f] = [(round(r["lift_off"], 3), r["touchdown"] and
                                     round(r["touchdown"], 3),
                                     r["length"] and round(r["length"], 3))
                                    for r in out.get("steps", [])]
                best = max(survived) if survived else None
                rows.append({"duration": dur, "direction": direction, "stepping": stepping,
                             "survived": survived, "largest": best, "steps": steps})
                print(f"duration {dur:g} s  {direction:8s}  stepping {str(stepping):5s}  "
                      f"largest survived {best} N  survived {survived}", flush=True)
                if stepping:
                    for f, st in steps.items():
                        print(f"    {f:g} N: steps (lift-off s, touch-down s, length m) {st}",
                              flush=True)
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
