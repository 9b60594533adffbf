"""Cost per degree of freedom: each character's quiet stance, full controller against raw ODE
stepping and against the model terms alone, measured in one process (docs/benchmarks.md).

For every character file named (default: humanoid, lion), after a warm-up (numba compilation):
  * raw ODE: `sim.bench.raw_ode_cpu_per_second` (the world with its heel/toe contacts, no
    controller), CPU s per simulated s;
  * model: `sim.dynamics.step_model` (M, h, momentum rows, J_s) per step, CPU s per simulated s;
  * QP: one `MomentumController.solve` per step as if at 1 kHz, then scaled to its 60 Hz;
  * full: `Rollout.run` of the quiet-stance clip (everything), CPU s per simulated s.
It prints one row per character and the ratios lion / humanoid per DOF.

    .venv/bin/python bench/dof_scaling.py [--seconds 5] [--characters humanoid lion] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from sim.bench import raw_ode_cpu_per_second
from sim.controllers.momentum import QP_RATE
from sim.dynamics import momentum_bias, step_model
from sim.physics import DT
from sim.rollout import Rollout
from sim.spec import parse_spec


def _spec(model: str, seconds: float):
    return parse_spec({"name": f"dof_{model}", "character": {"model": model},
                       "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": seconds, "decay": 0.0}})


def measure(model: str, seconds: float) -> dict[str, float | int | str]:
    """The four rates (CPU s per simulated s) of one character's quiet stance."""
    sim = Rollout(_spec(model, seconds))
    sim.run()  # warm-up
    ch, a = sim.character, sim.arrays
    raw = raw_ode_cpu_per_second(sim, seconds)
    margs = a.args() + (a.feet, a.sole_local, a.heel_local, a.toe_local, a.point_body,
                        a.point_local, a.point_radius)
    q, qd = sim.q0.copy(), np.zeros(ch.ndof)
    steps = int(round(seconds / DT))
    t0 = time.process_time()
    for _ in range(steps):
        out = step_model(q, qd, *margs)
    model_rate = (time.process_time() - t0) / seconds
    M, h, c, cd, A_L, A_H, Js, pts, sole_x, lo, hi, _clear = out
    ctl = sim.controller
    ctl.reset()
    n_qp = max(steps // 10, 1)
    t0 = time.process_time()
    for k in range(n_qp):
        ctl.solve(k * DT, q, qd, c, cd, A_L, A_H, Js, (lo, hi), (0.5 * (lo + hi), 0.0),
                  (0.0, 0.0), lambda: momentum_bias(q, qd, a.parent, a.a_par, a.a_chi,
                                                    a.mass, a.feet, a.sole_local))
    qp_rate = (time.process_time() - t0) / n_qp * QP_RATE
    t0 = time.process_time()
    ev = sim.run()
    full = (time.process_time() - t0) / ev.sim_seconds
    sim.close()
    return {"character": model, "dof": ch.ndof, "bodies": ch.n_bodies, "stood": not ev.fell,
            "raw_ode": raw, "model_terms": model_rate, "qp_60hz": qp_rate, "full": full,
            "full_over_raw": full / raw}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--characters", nargs="+", default=["humanoid", "lion"])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = [measure(m, args.seconds) for m in args.characters]
    if args.json:
        print(json.dumps(rows))
        return
    keys = ("raw_ode", "model_terms", "qp_60hz", "full")
    print("character  dof  " + "  ".join(f"{k:>11}" for k in keys) + "  full/raw")
    for r in rows:
        print(f"{r['character']:<10} {r['dof']:>3}  "
              + "  ".join(f"{r[k]:11.4f}" for k in keys) + f"  {r['full_over_raw']:8.2f}")
    base = rows[0]
    for r in rows[1:]:
        dof = r["dof"] / base["dof"]
        print(f"{r['character']} / {base['character']}: DOF x{dof:.2f}; "
              + ", ".join(f"{k} x{r[k] / base[k]:.2f}" for k in keys))


if __name__ == "__main__":
    main()
