"""The punch mismatch (paper Figure 11, bottom) measured step by step: why the miss falls.

    .venv/bin/python bench/punch_miss.py --cmrt RESULT.json [--spec examples/punch_miss.yaml]
                                         [--hit-spec examples/punch.yaml] [--json]

For the miss scene with the punch's CMRT (and, for contrast, the hit scene with it and the miss
without it) it records every step under the default balance controller and prints:
  * the timeline (every 25 ms over 0.9-1.6 s): CM x and the CM reference x relative to the
    support centre, the CM's horizontal speed, its capture point x_cp = c_x + v_x sqrt(c_y / g)
    relative to the toe edge, the highest stance heel/toe, the right elbow angle (its stop is
    0 deg);
  * the arm on a miss: the fists' peak speed and when the elbows reach their stop;
  * the hand-over: when the balance-lost rule fires, and where the capture point is then
    (beyond the toe edge: no ankle strategy can bring the CM back over the feet; the CM would
    need a step);
  * variants that change nothing in the controller's defaults: the hand-over rules lifted
    (the clip runs on to a physical fall or the end), and the CMRT released when the punch
    meets nothing (its displacement eased to 0 over `--release-ramp` s from `--release-at`),
    i.e. what the reactive controller alone does from that moment.
No assertions (an experiment, docs/benchmarks.md, "The punch mismatch").
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sim.controllers.momentum as momentum  # noqa: E402
from optim.result import OptimizationResult  # noqa: E402
from sim.character import ROOT_DOF  # noqa: E402
from sim.dynamics import GRAVITY  # noqa: E402
from sim.rollout import Rollout  # noqa: E402
from sim.spec import load_spec  # noqa: E402

#: Timeline rows: every this many seconds over TIMELINE.
TIMELINE_STEP = 0.025
TIMELINE = (0.9, 1.6)


def _quintic(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def released(cmrt: Any, at: float, ramp: float) -> Callable[[float], Any]:
    """The CMRT until `at`, then its value there eased to 0 over `ramp` s (a quintic)."""

    def f(t: float) -> Any:
        if t <= at:
            return cmrt(t)
        v = cmrt(at)
        w = 1.0 - _quintic((t - at) / ramp) if ramp > 0 else 0.0
        if isinstance(v, tuple | list):
            return tuple(w * float(x) for x in v)
        return w * float(v)

    return f


def held_lean(d: float, up: tuple[float, float] = (0.2, 0.9),
              down: tuple[float, float] = (1.5, 2.5)) -> Callable[[float], float]:
    """A hand-made CMRT: 0, eased to `d` m over `up`, held, eased back to 0 over `down`
    (quintic eases), so the CM arrives at the punch leaning but at rest."""

    def f(t: float) -> float:
        if t <= down[0]:
            return d * _quintic((t - up[0]) / (up[1] - up[0]))
        return d * (1.0 - _quintic((t - down[0]) / (down[1] - down[0])))

    return f


def record(spec: Any, cmrt: Any, no_handover: bool = False) -> dict[str, Any]:
    """Run the clip, recording the balance controller's observation every step."""
    saved = momentum.FOOT_LIFT_LIMIT, momentum.WRENCH_VIOLATION_LIMIT
    if no_handover:  # both are read by the controller: one at its build, one every step
        momentum.FOOT_LIFT_LIMIT = math.inf
        momentum.WRENCH_VIOLATION_LIMIT = math.inf
    try:
        return _record(Rollout(spec), cmrt)
    finally:
        momentum.FOOT_LIFT_LIMIT, momentum.WRENCH_VIOLATION_LIMIT = saved


def _record(sim: Rollout, cmrt: Any) -> dict[str, Any]:
    ch = sim.character
    ctl = sim.controller
    inner = ctl.act
    elbows = [ch.hinge_index(n) for n in ("elbow_r", "elbow_l") if n in ch.hinge_names]
    hands = [ch.geom(h).body for h in ch.hands]
    phys = sim.physics
    rows: list[dict[str, float]] = []

    def act(obs: Any, t: float) -> Any:
        tau = inner(obs, t)
        lo, hi = obs.support
        s = 0.5 * (lo + hi)
        cx, cy = float(obs.c[0]), float(obs.c[1])
        vx = float(obs.cd[0])
        cap = cx + vx * math.sqrt(max(cy, 1e-9) / GRAVITY)
        speeds = []
        for b in hands:
            v = phys.bodies[b].getLinearVel()
            speeds.append(math.hypot(v[0], v[1]))
        rows.append({
            "t": t, "cm": cx - s, "cm_y": cy, "ref": float(ctl.c_ref[0]) - s, "vx": vx,
            "cap_toe": cap - hi, "cap": cap - s, "toe": hi - s,
            "lift": float(obs.points[:, 1].max()),
            "elbow_deg": [math.degrees(float(obs.q[ROOT_DOF + j])) for j in elbows],
            "hand_speed": max(speeds) if speeds else 0.0,
            "lost": ctl.lost,
        })
        return tau

    ctl.act = act
    try:
        ev = sim.run(cmrt)
    finally:
        sim.close()
    return {"evaluation": ev, "rows": rows}


def summary(rec: dict[str, Any]) -> dict[str, Any]:
    """Key figures of one recorded clip."""
    ev, rows = rec["evaluation"], rec["rows"]
    first_out = next((r for r in rows if r["cap_toe"] > 0.0), None)
    lift3 = next((r for r in rows if r["lift"] > 0.03), None)
    elbow_stop = next((r for r in rows if r["t"] > 1.0 and r["elbow_deg"]
                       and min(r["elbow_deg"]) < 0.5), None)
    last = rows[-1]
    return {
        "fell": ev.fell, "fall_time": ev.fall_time, "fall_reason": ev.fall_reason,
        "fall_direction": ev.fall_direction, "objective": ev.objective,
        "task_success": ev.task_success,
        "cm_at_1.0": next(r["cm"] for r in rows if r["t"] >= 1.0 - 1e-9),
        "ref_at_1.0": next(r["ref"] for r in rows if r["t"] >= 1.0 - 1e-9),
        "toe": rows[0]["toe"],
        "peak_hand_speed": max(r["hand_speed"] for r in rows if 1.0 <= r["t"] <= 1.3),
        "elbow_at_stop": None if elbow_stop is None else elbow_stop["t"],
        "capture_point_beyond_toe": None if first_out is None else first_out["t"],
        "largest_capture_point_excess": max(r["cap_toe"] for r in rows),
        "heel_lift_3cm": None if lift3 is None else lift3["t"],
        "capture_point_excess_at_end": last["cap_toe"], "end_t": last["t"],
        "largest_lift": max(r["lift"] for r in rows),
    }


def timeline(rec: dict[str, Any]) -> list[str]:
    out = []
    next_t = TIMELINE[0]
    for r in rec["rows"]:
        if r["t"] + 1e-9 >= next_t and r["t"] <= TIMELINE[1] + 1e-9:
            el = "/".join(f"{e:.0f}" for e in r["elbow_deg"])
            out.append(f"  {r['t']:.3f}  cm {100 * r['cm']:+6.1f}  ref {100 * r['ref']:+6.1f}  "
                       f"vx {r['vx']:+.3f}  capture-toe {100 * r['cap_toe']:+6.1f}  "
                       f"lift {100 * r['lift']:5.2f}  elbow {el}  hand {r['hand_speed']:.2f}")
            next_t += TIMELINE_STEP
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cmrt", required=True, help="the punch's result file (cmrt optimize --out)")
    ap.add_argument("--spec", default="examples/punch_miss.yaml")
    ap.add_argument("--hit-spec", default="examples/punch.yaml")
    ap.add_argument("--release-at", type=float, nargs="*", default=[1.1],
                    help="times (s) at which the CMRT is released in the release variant")
    ap.add_argument("--release-ramp", type=float, default=0.1)
    ap.add_argument("--lean", type=float, nargs="*", default=[0.04, 0.06, 0.08],
                    help="hand-made held leans (m) simulated with the bag and without it")
    ap.add_argument("--timelines", action="store_true", help="print every case's timeline")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    miss, hit = load_spec(args.spec), load_spec(args.hit_spec)
    cmrt = OptimizationResult.load(args.cmrt).spline()
    cases: list[tuple[str, Any, Any, bool]] = [
        ("hit, CMRT", hit, cmrt, False),
        ("miss, CMRT", miss, cmrt, False),
        ("miss, no CMRT", miss, None, False),
        ("miss, CMRT, no hand-over", miss, cmrt, True),
    ]
    for d in args.lean:
        lean = held_lean(d)
        cases += [(f"hit, held lean {100 * d:g} cm", hit, lean, False),
                  (f"miss, held lean {100 * d:g} cm", miss, lean, False),
                  (f"miss, held lean {100 * d:g} cm, no hand-over", miss, lean, True)]
    for at in args.release_at:
        cases.append((f"miss, CMRT released at {at:g} s over {args.release_ramp:g} s", miss,
                      released(cmrt, at, args.release_ramp), False))
    results = []
    for name, spec, c, noh in cases:
        rec = record(spec, c, noh)
        results.append({"case": name, **summary(rec), "timeline": timeline(rec)})
    if args.json:
        print(json.dumps(results, indent=1, default=str))
        return 0
    for r in results:
        fall = (f"fell {r['fall_time']:.3f} s {r['fall_direction']} ({r['fall_reason']})"
                if r["fell"] else "stands")

        def t(v: float | None) -> str:
            return "never" if v is None else f"{v:.3f} s"

        print(f"{r['case']}: {fall}, objective {r['objective']:.4f}, task {r['task_success']}")
        print(f"  at 1.0 s: CM {100 * r['cm_at_1.0']:+.1f} cm, reference "
              f"{100 * r['ref_at_1.0']:+.1f} cm from the support centre (toe edge "
              f"{100 * r['toe']:+.1f}); fist peak {r['peak_hand_speed']:.2f} m/s, elbow at its "
              f"stop {t(r['elbow_at_stop'])}")
        print(f"  capture point beyond the toe from {t(r['capture_point_beyond_toe'])}, largest "
              f"excess {100 * r['largest_capture_point_excess']:+.1f} cm; heel/toe lift 3 cm "
              f"{t(r['heel_lift_3cm'])}, largest lift {100 * r['largest_lift']:.1f} cm; last "
              f"step {r['end_t']:.3f} s, capture point "
              f"{100 * r['capture_point_excess_at_end']:+.1f} cm from the toe")
        if args.timelines or r["case"] in ("miss, CMRT", "hit, CMRT"):
            print("\n".join(r["timeline"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
