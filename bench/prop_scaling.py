"""Cost per prop and per contact: the humanoid's quiet stance with 0..N boxes added to its
world, full controller against ODE stepping of the same world, in one process
(docs/benchmarks.md, "Speed (issue 15)").

The boxes (0.3 x 0.2 m, 10 kg) are placed beside the character, clear of it, in one of two
layouts: `row` (each on the ground, 0.5 m apart: 2 prop-ground contacts each) or `stack`
(one column: 2 contacts per box, on the ground or on the box below). The controller does not
model them; they only load ODE (bodies, contact rows) and the collision pass. For every N:
  * raw ODE: `sim.bench.raw_ode_cpu_per_second` (the world with its heel/toe contacts and the
    boxes collided each step, no controller), CPU s per simulated s;
  * replay: `sim.bench.replay_ode_cpu_per_second` (the clip's own world, the controller's
    torques and contact points replayed open loop);
  * full: `Rollout.run` of the quiet-stance clip (everything);
  * contacts: foot contacts and prop contacts per step, averaged over raw ODE stepping of the
    same world (the standing pose, no controller).

    .venv/bin/python bench/prop_scaling.py [--seconds 3] [--props 0 1 2 4 8] [--layout row]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from sim.bench import RAW_RESET_SECONDS, raw_ode_cpu_per_second, replay_ode_cpu_per_second
from sim.physics import DT
from sim.props import PropDef
from sim.rollout import Rollout
from sim.spec import parse_spec

BOX_SIZE = (0.3, 0.2)  # m, width along x and height
BOX_MASS = 10.0  # kg
ROW_START = 0.8  # m, x of the first box's centre (the toes are near x = 0.2)
ROW_GAP = 0.5  # m between box centres in a row


def boxes(count: int, layout: str) -> list[PropDef]:
    """`count` resting boxes, clear of the character."""
    w, h = BOX_SIZE
    if layout == "row":
        return [PropDef(f"box{k}", "box", BOX_SIZE, BOX_MASS, (ROW_START + ROW_GAP * k, 0.5 * h))
                for k in range(count)]
    return [PropDef(f"box{k}", "box", BOX_SIZE, BOX_MASS, (ROW_START, (k + 0.5) * h))
            for k in range(count)]


def contacts_per_step(sim: Rollout, seconds: float) -> tuple[float, float]:
    """(foot contacts, prop contacts) per step of `sim`'s world stepped as the raw ODE case
    steps it (`sim.bench.raw_ode_cpu_per_second`: heel and toe contacts at the standing pose,
    props collided, reset every RAW_RESET_SECONDS), counted after each step (not timed)."""
    phys, ch = sim.physics, sim.character
    pts = np.concatenate([[h, t] for h, t in zip(ch.heel0, ch.toe0, strict=True)])
    pts[:, 1] = 0.0
    feet = np.repeat(ch.feet, 2).tolist()
    steps = int(round(seconds / DT))
    every = int(round(RAW_RESET_SECONDS / DT))
    foot = prop = 0
    for k in range(steps):
        if k % every == 0:
            phys.reset(sim.q0)
        phys.make_contacts(pts, feet)
        phys.collide_props()
        phys.step()
        phys.contact_forces()
        foot += len(phys.contacts)
        prop += len(phys.prop_contacts)
        phys.clear_contacts()
    return foot / steps, prop / steps


def measure(count: int, layout: str, seconds: float) -> dict[str, float | int | str]:
    """The three rates (CPU s per simulated s) and contacts per step with `count` boxes."""
    spec = parse_spec({"name": f"props_{layout}_{count}", "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": seconds, "decay": 0.0}})
    sim = Rollout(spec, extra_props=boxes(count, layout))
    sim.run()  # warm-up
    raw = raw_ode_cpu_per_second(sim, seconds)
    t0 = time.process_time()
    ev = sim.run()
    full = (time.process_time() - t0) / ev.sim_seconds
    replay, _s, same = replay_ode_cpu_per_second(sim)
    feet, props = contacts_per_step(sim, seconds)
    sim.close()
    return {"layout": layout, "props": count, "stood": not ev.fell,
            "foot_contacts": feet, "prop_contacts": props,
            "raw_ode": raw, "replay_ode": replay, "full": full, "full_over_raw": full / raw,
            "full_over_replay": full / replay, "controller_cost": full - replay,
            "replay_reproduced_clip": same}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--props", type=int, nargs="+", default=[0, 1, 2, 4, 8])
    ap.add_argument("--layout", choices=["row", "stack"], default="row")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = [measure(n, args.layout, args.seconds) for n in args.props]
    if args.json:
        print(json.dumps(rows))
        return
    print(f"{'props':>5} {'contacts':>9} {'raw ODE':>8} {'replay':>8} {'full':>8} "
          f"{'full/raw':>8} {'full/replay':>11} {'full-replay':>11}")
    for r in rows:
        contacts = r["foot_contacts"] + r["prop_contacts"]
        print(f"{r['props']:>5} {contacts:>9.1f} {r['raw_ode']:>8.4f} {r['replay_ode']:>8.4f} "
              f"{r['full']:>8.4f} {r['full_over_raw']:>8.2f} {r['full_over_replay']:>11.2f} "
              f"{r['controller_cost']:>11.4f}")


if __name__ == "__main__":
    main()
