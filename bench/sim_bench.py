"""CPU cost of the simulation per simulated second: raw ODE stepping vs the full controller.

    .venv/bin/python bench/sim_bench.py [--json] [--raw-seconds 2] [--clip-seconds 5]

(i)  raw: the humanoid's ODE world with ground contacts at the heels and toes, stepped at 1 ms
     with no balance controller: each step reads the state, applies constant torques that hold
     the standing pose statically plus the fall controller's low-stiffness PD, makes the heel
     and toe contacts (points from ODE's bodies), steps, reads the contact feedback and clears
     the contacts (what `Rollout.run` does around its controller).
(ii) full: `Rollout.run` on a quiet-stance clip (momentum QP at 60 Hz, numba model and
     checked inverse dynamics every step, fall detection, CP measurement).
Both are measured in one process with `time.process_time` (CPU seconds, so other jobs on the
machine inflate wall time but not these numbers), after a warm-up that loads or compiles the
numba functions and runs both loops once; the warm-up time is reported separately, excluded.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from sim.character import ROOT_DOF
from sim.dynamics import inverse_dynamics, step_model
from sim.physics import DT
from sim.rollout import Rollout
from sim.spec import parse_spec


def quiet_spec(seconds: float):
    return parse_spec({"name": "bench_quiet", "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": seconds, "decay": 0.0}})


def raw_loop(sim: Rollout, steps: int) -> dict[str, float]:
    """Step the simulator's own world without the controller; returns CPU s and a sanity
    check (the CM height at the end, the number of contact joints made)."""
    w, ch, a = sim.physics, sim.character, sim.arrays
    fall = sim.fall_controller
    w.reset(sim.q0)
    fall.engage(sim.q0[ROOT_DOF:])
    # Torques that hold the standing pose statically (inverse dynamics once, before the loop),
    # so that the PD only corrects drift and the feet keep all their contacts.
    r = step_model(sim.q0, np.zeros(ch.ndof), *a.args(), a.feet, a.sole_local, a.heel_local,
                   a.toe_local, a.point_body, a.point_local, a.point_radius)
    hold, _ = inverse_dynamics(r[0], r[1], r[6], np.zeros(ch.ndof))
    feet = [w.bodies[int(f)] for f in ch.feet]
    local = [(tuple(a.heel_local[i]) + (0.0,), tuple(a.toe_local[i]) + (0.0,))
             for i in range(len(feet))]
    foot_of_point = np.repeat(ch.feet, 2)
    pts = np.empty((2 * len(feet), 2))
    contacts = 0
    cpu0 = time.process_time()
    for _ in range(steps):
        q, qd = w.read_state()
        w.apply_torques(hold + fall.torques(q[ROOT_DOF:], qd[ROOT_DOF:]))
        for i, body in enumerate(feet):
            for k in range(2):
                x, y, _ = body.getRelPointPos(local[i][k])
                pts[2 * i + k] = (x, y)
        w.make_contacts(pts, foot_of_point)
        contacts += len(w.contacts)
        w.step()
        w.contact_forces()
        w.clear_contacts()
    cpu = time.process_time() - cpu0
    w.clear_contacts()
    return {"cpu": cpu, "root_height": float(w.read_state()[0][1]),
            "contacts_per_step": contacts / steps}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--raw-seconds", type=float, default=2.0)
    ap.add_argument("--clip-seconds", type=float, default=5.0)
    args = ap.parse_args(argv)

    # Warm-up: numba functions (cached on disk after the first run, compiled otherwise),
    # PyODE, and one short pass through both loops.
    w0 = time.process_time()
    warm = Rollout(quiet_spec(0.2))
    warm.run()
    raw_loop(warm, 200)
    warm.close()
    warmup = time.process_time() - w0

    sim = Rollout(quiet_spec(args.clip_seconds))
    raw_steps = int(round(args.raw_seconds / DT))
    raw = raw_loop(sim, raw_steps)
    raw_per_s = raw["cpu"] / (raw_steps * DT)
    ev = sim.run()
    sim.close()
    full_per_s = ev.cpu_seconds / ev.sim_seconds

    out = {
        "raw_ode_cpu_per_sim_s": raw_per_s,
        "full_controller_cpu_per_sim_s": full_per_s,
        "ratio_full_over_raw": full_per_s / raw_per_s,
        "raw_sim_seconds": raw_steps * DT,
        "raw_contacts_per_step": raw["contacts_per_step"],
        "raw_final_root_height_m": raw["root_height"],
        "standing_root_height_m": float(sim.q0[1]),
        "full_sim_seconds": ev.sim_seconds,
        "full_fell": ev.fell,
        "warmup_cpu_s_excluded": warmup,
    }
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"raw ODE stepping (contacts, PD hold, no controller): {raw_per_s:.3f} CPU s per "
          f"simulated s ({raw_steps * DT:g} s simulated, {raw['contacts_per_step']:.1f} "
          f"contacts/step)")
    print(f"full controller, quiet stance (Rollout.run):        {full_per_s:.3f} CPU s per "
          f"simulated s ({ev.sim_seconds:g} s simulated, fell={ev.fell})")
    print(f"ratio full / raw:                                     {full_per_s / raw_per_s:.2f}")
    print(f"warm-up (numba load/compile, first runs), excluded:   {warmup:.2f} CPU s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
