"""The punch mismatch (paper Figure 11, bottom) measured step by step: why the miss falls.

    .venv/bin/python bench/punch_miss.py --cmrt RESULT.json [--spec examples/punch_miss.yaml]
        [--hit-spec examples/punch.yaml] [--release-at T ...] [--release-ramp S]
        [--release-time S] [--lean D ...] [--bag-mass M ...] [--lenient] [--stepping]
        [--timelines] [--json]

For the miss scene with the punch's CMRT (and, for contrast, the hit scene with it and the miss
without it) it records every step under the default balance controller and prints:
  * the timeline (every 25 ms over 0.9-1.6 s): CM x and the CM reference x relative to the
    support centre, the CM's horizontal speed, its capture point x_cp = c_x + v_x sqrt(c_y / g)
    relative to the toe edge, the highest stance heel/toe, the right elbow angle (its stop is
    0 deg);
  * the arm on a miss: the fists' peak speed and when the elbows reach their stop;
  * the hand-over: when the balance-lost rule fires, and where the capture point is then
    (beyond the toe edge: no ankle strategy can bring the CM back over the feet; the CM would
    need a step); when the rollout released the CMRT (the task reported the miss,
    `Task.interaction_failed`: at the end of the first punch), and the capture point relative
    to the toe at 1.0 s (the punch starts), at the first hit time of the hit scene, and then;
  * variants that change nothing in the controller's defaults: the hand-over rules lifted
    (heel/toe lift and inadmissible-wrench time: the clip runs on to a physical fall or the
    end; with `--lenient` also the pulling-ground rule, so only a physical fall ends a clip),
    and the CMRT released earlier than the task can know of the miss (an oracle:
    `sim.rollout.ReleasableCmrt` released at each `--release-at`, eased to 0 over
    `--release-ramp` s), i.e. what the reactive controller alone does from that moment;
    `--release-time` changes the rollout's own release ease for the run (sensitivity);
  * with `--bag-mass`: the hit scene with a lighter bag than the CMRT was made for (paper
    6.1.4: "if the bag is much lighter than expected"), the rules on and lifted;
  * with `--stepping`: the same scenes with the character's step controller on
    (`controller: {type: momentum, stepping: true}`, its defaults), and the steps it took.
No assertions (an experiment, docs/benchmarks.md, "The punch mismatch").
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from typing import Any

import sim.controllers.momentum as momentum
import sim.rollout as rollout
from optim.result import OptimizationResult
from sim.character import ROOT_DOF
from sim.dynamics import GRAVITY
from sim.rollout import ReleasableCmrt, Rollout
from sim.spec import load_spec, parse_spec

#: Timeline rows: every this many seconds over TIMELINE.
TIMELINE_STEP = 0.025
TIMELINE = (0.9, 1.6)


def _quintic(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


def released(cmrt: Any, at: float, ramp: float) -> ReleasableCmrt:
    """The CMRT until `at`, then its value there eased to 0 over `ramp` s: the rollout's own
    release (`sim.rollout.ReleasableCmrt`), triggered at a chosen time."""
    out = ReleasableCmrt(cmrt, ramp)
    out.release(at)
    return out


def held_lean(d: float, up: tuple[float, float] = (0.2, 0.9),
              down: tuple[float, float] = (1.5, 2.5)) -> Callable[[float], float]:
    """A hand-made CMRT: 0, eased to `d` m over `up`, held, eased back to 0 over `down`
    (quintic eases), so the CM arrives at the punch leaning but at rest."""

    def f(t: float) -> float:
        if t <= down[0]:
            return d * _quintic((t - up[0]) / (up[1] - up[0]))
        return d * (1.0 - _quintic((t - down[0]) / (down[1] - down[0])))

    return f


#: A wrench code no inverse dynamics returns: the pulling-ground rule never fires with it.
NO_SUCH_CODE = -1


def record(spec: Any, cmrt: Any, no_handover: bool = False,
           lenient: bool = False) -> dict[str, Any]:
    """Run the clip, recording the balance controller's observation every step.

    no_handover: the heel/toe-lift and inadmissible-wrench-time rules lifted; lenient: also
    the pulling-ground rule (only a physical fall ends the clip)."""
    saved = (momentum.FOOT_LIFT_LIMIT, momentum.WRENCH_VIOLATION_LIMIT,
             momentum.WRENCH_NO_NORMAL_FORCE)
    if no_handover or lenient:  # read by the controller: the first at its build, then every step
        momentum.FOOT_LIFT_LIMIT = math.inf
        momentum.WRENCH_VIOLATION_LIMIT = math.inf
    if lenient:
        momentum.WRENCH_NO_NORMAL_FORCE = NO_SUCH_CODE
    try:
        return _record(Rollout(spec), cmrt)
    finally:
        (momentum.FOOT_LIFT_LIMIT, momentum.WRENCH_VIOLATION_LIMIT,
         momentum.WRENCH_NO_NORMAL_FORCE) = saved


def with_bag_mass(spec: Any, mass: float) -> Any:
    """The spec with the bag's mass changed (kg)."""
    data = spec.model_dump(mode="json", exclude_none=True)
    data["task"]["mass"] = mass
    return parse_spec(data)


def with_stepping(spec: Any) -> Any:
    """The spec with the step controller on (its defaults)."""
    data = spec.model_dump(mode="json", exclude_none=True)
    data["controller"] = {"type": "momentum", "stepping": True}
    return parse_spec(data)


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
    steps = [{"start": st.start, "touchdown": st.touchdown, "length": st.length,
              "direction": st.direction} for st in getattr(ctl, "steps", [])]
    return {"evaluation": ev, "rows": rows, "steps": steps}


def _at(rows: list[dict[str, Any]], t: float, key: str) -> float | None:
    """`key` of the first recorded step at or after t (None if the clip ended before)."""
    return next((r[key] for r in rows if r["t"] >= t - 1e-9), None)


def summary(rec: dict[str, Any], hit_time: float | None = None) -> dict[str, Any]:
    """Key figures of one recorded clip (`hit_time`: the hit scene's first hit, s)."""
    ev, rows = rec["evaluation"], rec["rows"]
    released_at = ev.cmrt_released_at
    first_out = next((r for r in rows if r["cap_toe"] > 0.0), None)
    lift3 = next((r for r in rows if r["lift"] > 0.03), None)
    elbow_stop = next((r for r in rows if r["t"] > 1.0 and r["elbow_deg"]
                       and min(r["elbow_deg"]) < 0.5), None)
    last = rows[-1]
    return {
        "fell": ev.fell, "fall_time": ev.fall_time, "fall_reason": ev.fall_reason,
        "fall_direction": ev.fall_direction, "objective": ev.objective,
        "task_success": ev.task_success,
        "cm_at_1.0": _at(rows, 1.0, "cm"), "ref_at_1.0": _at(rows, 1.0, "ref"),
        "cmrt_released_at": released_at,
        "capture_toe_at_1.0": _at(rows, 1.0, "cap_toe"),
        "capture_toe_at_hit": None if hit_time is None else _at(rows, hit_time, "cap_toe"),
        "capture_toe_at_release": (None if released_at is None
                                   else _at(rows, released_at, "cap_toe")),
        "largest_cm": max(r["cm"] for r in rows),
        "steps": rec["steps"],
        "toe": rows[0]["toe"],
        "peak_hand_speed": max((r["hand_speed"] for r in rows if 1.0 <= r["t"] <= 1.3),
                               default=math.nan),
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


def _cases(args: argparse.Namespace, miss: Any, hit: Any, cmrt: Any
           ) -> list[tuple[str, Any, Any, bool, bool]]:
    """(name, spec, cmrt, no hand-over, lenient) of every case the flags ask for."""
    cases: list[tuple[str, Any, Any, bool, bool]] = [
        ("hit, CMRT", hit, cmrt, False, False),
        ("miss, CMRT", miss, cmrt, False, False),
        ("miss, no CMRT", miss, None, False, False),
        ("miss, CMRT, no hand-over", miss, cmrt, True, False),
    ]
    if args.lenient:
        cases.append(("miss, CMRT, lenient", miss, cmrt, False, True))
    for d in args.lean:
        lean = held_lean(d)
        cases += [(f"hit, held lean {100 * d:g} cm", hit, lean, False, False),
                  (f"miss, held lean {100 * d:g} cm", miss, lean, False, False),
                  (f"miss, held lean {100 * d:g} cm, no hand-over", miss, lean, True, False)]
    for at in args.release_at:
        name = f"miss, CMRT released at {at:g} s over {args.release_ramp:g} s"
        rel = released(cmrt, at, args.release_ramp)
        cases.append((name, miss, rel, False, False))
        if args.lenient:
            cases.append((name + ", lenient", miss, released(cmrt, at, args.release_ramp),
                          False, True))
    for m in args.bag_mass:
        light = with_bag_mass(hit, m)
        cases += [(f"hit, bag {m:g} kg, CMRT", light, cmrt, False, False),
                  (f"hit, bag {m:g} kg, CMRT, no hand-over", light, cmrt, True, False)]
        if args.lenient:
            cases.append((f"hit, bag {m:g} kg, CMRT, lenient", light, cmrt, False, True))
    if args.stepping:
        miss_s, hit_s = with_stepping(miss), with_stepping(hit)
        cases += [("stepping: hit, no CMRT", hit_s, None, False, False),
                  ("stepping: hit, CMRT", hit_s, cmrt, False, False),
                  ("stepping: miss, no CMRT", miss_s, None, False, False),
                  ("stepping: miss, CMRT", miss_s, cmrt, False, False)]
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cmrt", required=True, help="the punch's result file (cmrt optimize --out)")
    ap.add_argument("--spec", default="examples/punch_miss.yaml")
    ap.add_argument("--hit-spec", default="examples/punch.yaml")
    ap.add_argument("--release-at", type=float, nargs="*", default=[1.1],
                    help="times (s) at which the CMRT is released in the release variant")
    ap.add_argument("--release-ramp", type=float, default=0.1)
    ap.add_argument("--release-time", type=float,
                    help="s: the rollout's own release ease (sim.rollout.RELEASE_TIME) for "
                         "this run, to measure how much the outcome depends on it")
    ap.add_argument("--lean", type=float, nargs="*", default=[0.04, 0.06, 0.08],
                    help="hand-made held leans (m) simulated with the bag and without it")
    ap.add_argument("--bag-mass", type=float, nargs="*", default=[],
                    help="the hit scene with these lighter bags (kg), the rules on and lifted")
    ap.add_argument("--lenient", action="store_true",
                    help="also judge the miss and each release with only physical falls")
    ap.add_argument("--stepping", action="store_true",
                    help="also the hit and the miss with the step controller on")
    ap.add_argument("--timelines", action="store_true", help="print every case's timeline")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.release_time is not None:  # read by every run (Rollout.run)
        rollout.RELEASE_TIME = args.release_time
    miss, hit = load_spec(args.spec), load_spec(args.hit_spec)
    cmrt = OptimizationResult.load(args.cmrt).spline()
    hit_sim = Rollout(hit)
    try:
        hit_sim.run(cmrt)
        hit_time = hit_sim.task.hit_time
    finally:
        hit_sim.close()
    results = []
    for name, spec, c, noh, lenient in _cases(args, miss, hit, cmrt):
        rec = record(spec, c, noh, lenient)
        results.append({"case": name, **summary(rec, hit_time), "timeline": timeline(rec)})
    if args.json:
        print(json.dumps(results, indent=1, default=str))
        return 0

    def t(v: float | None) -> str:
        return "never" if v is None else f"{v:.3f} s"

    def cm(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:+.1f} cm"

    print(f"hit scene, CMRT: first hit {t(hit_time)}")
    for r in results:
        fall = (f"fell {r['fall_time']:.3f} s {r['fall_direction']} ({r['fall_reason']})"
                if r["fell"] else "stands")
        print(f"{r['case']}: {fall}, objective {r['objective']:.4f}, task {r['task_success']}, "
              f"CMRT released by the rollout {t(r['cmrt_released_at'])}")
        print(f"  at 1.0 s: CM {cm(r['cm_at_1.0'])}, reference {cm(r['ref_at_1.0'])} from the "
              f"support centre (toe edge {cm(r['toe'])}); fist peak "
              f"{r['peak_hand_speed']:.2f} m/s, elbow at its stop {t(r['elbow_at_stop'])}")
        print(f"  capture point from the toe: {cm(r['capture_toe_at_1.0'])} at 1.0 s, "
              f"{cm(r['capture_toe_at_hit'])} at the hit time, "
              f"{cm(r['capture_toe_at_release'])} at the release; beyond the toe from "
              f"{t(r['capture_point_beyond_toe'])}, largest excess "
              f"{cm(r['largest_capture_point_excess'])}; largest CM {cm(r['largest_cm'])}")
        print(f"  heel/toe lift 3 cm {t(r['heel_lift_3cm'])}, largest lift "
              f"{cm(r['largest_lift'])}; last step {r['end_t']:.3f} s, capture point "
              f"{cm(r['capture_point_excess_at_end'])} from the toe")
        for st in r["steps"]:
            length = "-" if st["length"] is None else f"{st['length']:.3f} m"
            print(f"  step: lift-off {t(st['start'])}, touch-down {t(st['touchdown'])}, "
                  f"length {length}, direction {st['direction']:+d}")
        if args.timelines or r["case"] in ("miss, CMRT", "hit, CMRT"):
            print("\n".join(r["timeline"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
