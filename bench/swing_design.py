"""The step controller's swing, measured: grids of pushes and one push's swing, solve by solve,
with the controller's named constants set for the run (designs compared on grids, not on one
fall time: a single clip's outcome flips on tiny numerical changes).

    .venv/bin/python bench/swing_design.py grid [--set NAME=VALUE ...] [--forces 50 400 25]
        [--duration 0.4]
    .venv/bin/python bench/swing_design.py case --force 300 [--backward] [--set NAME=VALUE ...]
        [--every 4]

`grid`: examples/step_push.yaml at every force (both directions), the table of `cmrt sweep`
and, per direction, the survived set, the planned and landed x of each first step (their
difference: how far the swing landed from its plan). `case`: one push, every `--every`-th swing
QP solve of each step: planned - actual swing sole x and y (cm), the swing foot's pitch and the
IK - actual pelvis angle (deg), the QP's planned normal force (N) and CoP; then the steps.
Constants are set on `sim.controllers.stepping` in this process (`--set PELVIS_WEIGHT=0`), so
the grid runs its clips here (one worker).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import sim.controllers.stepping as stepping
from optim.executors import SerialExecutor
from optim.sweep import PushGrid, cell_document, run_grid, spec_document, table
from sim.rollout import Rollout
from sim.spec import load_spec, parse_spec

SPEC = Path(__file__).resolve().parents[1] / "examples" / "step_push.yaml"


def apply(settings: list[str]) -> None:
    for item in settings:
        name, value = item.split("=", 1)
        if not hasattr(stepping, name):
            raise SystemExit(f"--set: no constant {name} in sim.controllers.stepping")
        old = getattr(stepping, name)
        setattr(stepping, name, type(old)(value) if not isinstance(old, bool)
                else value.lower() in ("1", "true", "yes"))


def run_case(force: float, duration: float, direction: str, every: int,
             controller: str | None) -> None:
    spec = base_spec(controller)
    sim = Rollout(parse_spec(cell_document(spec_document(spec), force, duration, direction)))
    try:
        ev = sim.run(None)
    finally:
        sim.close()
    ctl = sim.controller
    print(f"{force:g} N x {duration:g} s {direction}: "
          + (f"fell {ev.fall_time:.3f} s {ev.fall_reason}" if ev.fell else "stands")
          + f", objective {ev.objective:.4f}")
    for i, r in enumerate(ctl.steps):
        print(f"step {i + 1}: lift-off {r.start:.3f} s, touch-down "
              f"{'-' if r.touchdown is None else f'{r.touchdown:.3f} s'}, planned land x "
              f"{r.plan.land[0]:+.3f} m (last re-plan "
              f"{(r.replans[-1][1] if r.replans else r.plan.land[0]):+.3f}), landed "
              f"{'-' if r.land_x is None else f'{r.land_x:+.3f}'}")
        solves = {round(s[0], 4): s for s in r.solves}
        for k, tr in enumerate(r.tracking):
            if k % every:
                continue
            t, ex, ey, pitch, pel = tr
            sv = solves.get(round(t, 4))
            extra = "" if sv is None else (f"  normal {sv[4]:7.1f} N  CoP {sv[1]:+.3f} in "
                                           f"[{sv[2]:+.3f}, {sv[3]:+.3f}]")
            print(f"  {t:.3f}  foot dx {100 * ex:+6.1f} dy {100 * ey:+5.1f} cm  pitch "
                  f"{math.degrees(pitch):+6.1f}  pelvis err {math.degrees(pel):+6.1f} deg{extra}")


def step_text(r: object) -> str:
    land = r.replans[-1][1] if r.replans else r.plan.land[0]
    got = "-" if r.land_x is None else f"{r.land_x:+.2f}"
    td = "-" if r.touchdown is None else f"{r.touchdown - r.start:.2f}"
    return f"{r.direction:+d}: plan {land:+.2f} got {got} ({td} s)"


def base_spec(controller: str | None) -> object:
    """examples/step_push.yaml with these controller-block fields (JSON) added."""
    spec = load_spec(SPEC)
    if not controller:
        return spec
    doc = spec_document(spec)
    doc["controller"] = {**doc["controller"], **json.loads(controller)}
    return parse_spec(doc)


def run_grid_cmd(forces: list[float], duration: float, detail: bool,
                 controller: str | None) -> None:
    spec = base_spec(controller)
    if not detail:
        grid = PushGrid(spec, forces, [duration])
        print(table(grid, run_grid(grid, SerialExecutor())))
        return
    for direction in ("forward", "backward"):
        ok = []
        for f in forces:
            sim = Rollout(parse_spec(cell_document(spec_document(spec), f, duration,
                                                   direction)))
            try:
                ev = sim.run(None)
            finally:
                sim.close()
            ok.append(not ev.fell)
            head = "stands" if not ev.fell else f"fell {ev.fall_time:.3f} {ev.fall_reason}"
            steps = "; ".join(step_text(r) for r in sim.controller.steps)
            print(f"{direction[:3]} {f:5g} N  {head:40s} {steps}", flush=True)
        print(f"{direction}: survived {sum(ok)} of {len(ok)}: "
              f"{[f for f, o in zip(forces, ok, strict=True) if o]}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("grid")
    g.add_argument("--forces", type=float, nargs=3, default=[50.0, 400.0, 25.0])
    g.add_argument("--duration", type=float, default=0.4)
    g.add_argument("--detail", action="store_true",
                   help="each clip's fall reason and steps (plan vs landed x)")
    c = sub.add_parser("case")
    c.add_argument("--force", type=float, default=300.0)
    c.add_argument("--duration", type=float, default=0.4)
    c.add_argument("--backward", action="store_true")
    c.add_argument("--every", type=int, default=4)
    for sp in (g, c):
        sp.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE")
        sp.add_argument("--controller", default=None, metavar="JSON",
                        help='the spec\'s controller-block fields, e.g. \'{"clearance": 0.08}\'')
    args = ap.parse_args()
    apply(args.set)
    if args.cmd == "case":
        run_case(args.force, args.duration, "backward" if args.backward else "forward",
                 args.every, args.controller)
        return
    first, last, step = args.forces
    forces = [first + k * step for k in range(int(round((last - first) / step)) + 1)]
    run_grid_cmd(forces, args.duration, args.detail, args.controller)


if __name__ == "__main__":
    main()
