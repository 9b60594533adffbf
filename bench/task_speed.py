"""CPU seconds per simulated second of whole task clips, next to raw ODE stepping of the same
world (its props included), measured in one process.

    .venv/bin/python bench/task_speed.py examples/quiet_stance.yaml examples/catch.yaml [--json]

For each spec: (i) `Rollout.run` without a CMRT (the clip's full loop: model terms, QP at
60 Hz, inverse dynamics, task events, contacts, measurement); per simulated second of what
was simulated (a clip that falls stops early); (ii) raw: the same Physics reset to the
clip's initial state and stepped for the clip's length with the feet's four ground contacts
made from the standing pose's heel and toe points, prop collisions, no controller, no
torques (reset every 0.5 s so the character stays standing). CPU time (`time.process_time`),
after a warm-up run; other jobs on the machine inflate wall time, not these numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.physics import DT  # noqa: E402
from sim.rollout import Rollout  # noqa: E402
from sim.spec import load_spec  # noqa: E402

RAW_RESET_SECONDS = 0.5


def raw_cpu_per_second(sim: Rollout, seconds: float) -> float:
    ph, ch = sim.physics, sim.character
    pts = np.concatenate([[h, t] for h, t in zip(ch.heel0, ch.toe0, strict=True)])
    pts[:, 1] = 0.0
    feet = np.repeat(ch.feet, 2).tolist()
    steps = int(round(seconds / DT))
    every = int(round(RAW_RESET_SECONDS / DT))
    cpu = 0.0
    for k in range(steps):
        if k % every == 0:
            ph.reset(sim.q0)
            sim.task.reset(ph)
        t0 = time.process_time()
        ph.make_contacts(pts, feet)
        ph.collide_props()
        ph.step()
        ph.contact_forces()
        ph.clear_contacts()
        cpu += time.process_time() - t0
    return cpu / seconds


def measure(path: str) -> dict[str, float | str | bool]:
    spec = load_spec(path)
    sim = Rollout(spec)
    try:
        sim.run()  # warm-up
        t0 = time.process_time()
        ev = sim.run()
        full = (time.process_time() - t0) / ev.sim_seconds
        raw = raw_cpu_per_second(sim, spec.clip.length)
    finally:
        sim.close()
    return {"spec": spec.name, "props": len(sim.physics.props), "fell": ev.fell,
            "simulated_seconds": ev.sim_seconds, "controller_cpu_per_sim_second": full,
            "raw_ode_cpu_per_sim_second": raw, "controller_over_raw_ode": full / raw}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("specs", nargs="+")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = [measure(p) for p in args.specs]
    if args.json:
        print(json.dumps(rows))
        return
    for r in rows:
        print(f"{r['spec']:>16}: controller {r['controller_cpu_per_sim_second']:.4f} s/s, raw ODE "
              f"{r['raw_ode_cpu_per_sim_second']:.4f} s/s, ratio {r['controller_over_raw_ode']:.2f}"
              f" ({r['props']} props, {r['simulated_seconds']:.3f} s simulated, fell "
              f"{r['fell']})")


if __name__ == "__main__":
    main()
