"""Pushes near the CM with and without stepping (the stepping seed paper's Fig. 7 and 8).

    .venv/bin/python bench/stepping.py case --force 300 --duration 0.4 [--backward] [--stepping]
    .venv/bin/python bench/stepping.py sweep --durations 0.1 0.2 0.4 --tol 5

`case` prints one clip's outcome and, with stepping, the step (detection, lift-off,
touch-down, length, the QP's planned CoP inside the support at every swing solve);
`sweep` bisects the largest survived push per duration, forward and backward, both ways.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.controllers.stepping import SteppingController, SteppingParams  # noqa: E402
from sim.physics import DT, FRICTION_MU  # noqa: E402
from sim.rollout import Rollout  # noqa: E402
from sim.spec import parse_spec  # noqa: E402

PUSH_START = 1.0  # s
DECAY = 2.5  # s after the push


def push_spec(force: float, duration: float, direction: str, body: str,
              stepping: bool) -> dict:
    return {"name": "step_push", "clip": {"preparation": PUSH_START, "duration": duration,
                                          "decay": DECAY},
            "task": {"type": "push", "force": force, "direction": direction, "body": body},
            "controller": {"type": "momentum", "stepping": stepping}}


def rollout(force: float, duration: float, direction: str, stepping: bool, body: str,
            params: SteppingParams | None = None) -> Rollout:
    sim = Rollout(parse_spec(push_spec(force, duration, direction, body, stepping)))
    if stepping and params is not None:
        sim.controller = SteppingController(sim.character, sim.controller.feet_fixed.schedule,
                                            sim.trajectory, sim.arrays, dt=DT, mu=FRICTION_MU,
                                            params=params)
    return sim


def run_case(force, duration, direction, stepping, body, params=None, traces=False):
    sim = rollout(force, duration, direction, stepping, body, params)
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
                "ik_max_error": max((e for _t, e in r.ik_error), default=math.nan)})
        out["steps"] = steps
        out["phase"] = sim.controller.phase
    return out, ev


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("case")
    c.add_argument("--force", type=float, default=300.0)
    c.add_argument("--duration", type=float, default=0.4)
    c.add_argument("--backward", action="store_true")
    c.add_argument("--stepping", action="store_true")
    c.add_argument("--body", default="pelvis")
    s = sub.add_parser("sweep")
    s.add_argument("--durations", type=float, nargs="+", default=[0.1, 0.2, 0.4])
    s.add_argument("--lo", type=float, default=50.0)
    s.add_argument("--hi", type=float, default=800.0)
    s.add_argument("--tol", type=float, default=5.0)
    s.add_argument("--body", default="pelvis")
    args = ap.parse_args()
    if args.cmd == "case":
        out, _ = run_case(args.force, args.duration, "backward" if args.backward else "forward",
                          args.stepping, args.body)
        print(json.dumps(out, indent=1))
        return
    rows = []
    for dur in args.durations:
        for direction in ("forward", "backward"):
            for stepping in (False, True):
                lo, hi = args.lo, args.hi
                if run_case(lo, dur, direction, stepping, args.body)[0]["fell"]:
                    best = None
                else:
                    while hi - lo > args.tol:
                        mid = 0.5 * (lo + hi)
                        if run_case(mid, dur, direction, stepping, args.body)[0]["fell"]:
                            hi = mid
                        else:
                            lo = mid
                    best = lo
                rows.append((dur, direction, stepping, best))
                print(f"duration {dur:g} s  {direction:8s}  stepping {str(stepping):5s}  "
                      f"largest survived {best if best is None else round(best, 1)} N",
                      flush=True)
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
