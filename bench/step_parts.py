"""What each part of a control step costs alone: the floor of the controller over its replay.

    .venv/bin/python bench/step_parts.py [SPEC] [--number 20000]

Builds the spec's Rollout (default: the quiet stance), runs the clip once, then times each part
of a step on the state it ended in, alone, with `timeit` on `time.process_time` (the lowest of
5 repeats, microseconds per call): the parts only the controller pays (the state read, the
held step's compiled model terms + inverse dynamics + clamp, a QP step's `act`, applying the
clamped torques) and, for scale, those a replay of the clip pays as well (the feet's contacts
made and cleared, applying unclamped torques). No assertions.
"""

from __future__ import annotations

import argparse
import sys
import time
import timeit
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def parts(path: Path, number: int) -> dict[str, float]:
    """Microseconds per call of each part (see the module docstring)."""
    from sim.controllers.base import Observation
    from sim.dynamics import step_model_held, step_model_packed
    from sim.rollout import Rollout
    from sim.spec import load_spec

    r = Rollout(load_spec(path))
    r.run()
    phys, b, pack = r.physics, r.controller, r.pack
    q, qd = phys.read_state()
    pargs = pack.args()
    neg, lim = phys.torque_bounds
    tau = np.empty(len(lim))
    lo, hi, _ = step_model_packed(q, qd, *pargs)
    obs = Observation(q, qd, *pack.arrays()[:8], pack.sole_x, (lo, hi), None)
    feet = np.repeat(r.character.feet, 2).tolist()

    def qp_step() -> None:
        b._k = 0  # the next act solves the QP
        b.act(obs, 1.0)

    def contacts() -> None:
        phys.make_contacts(pack.pts, feet)
        phys.clear_contacts()

    cases = {
        "state read (read_state)": phys.read_state,
        "held step, compiled (step_model_held)": lambda: step_model_held(
            q, qd, *pargs, b.qdd, b.mu, neg, lim, tau),
        "model terms alone (step_model_packed)": lambda: step_model_packed(q, qd, *pargs),
        "QP step (act, 1 in qp_every steps)": qp_step,
        "clamped torques (add_clamped_torques)": lambda: phys.add_clamped_torques(tau.tolist()),
        "replay's torques (apply_torques)": lambda: phys.apply_torques(tau),
        "replay's contacts (make + clear)": contacts,
    }
    out = {name: min(timeit.repeat(fn, number=number, repeat=5, timer=time.process_time))
           / number * 1e6 for name, fn in cases.items()}
    out["qp_every"] = b.qp_every
    r.close()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("spec", nargs="?", default=str(ROOT / "examples/quiet_stance.yaml"))
    ap.add_argument("--number", type=int, default=20000)
    args = ap.parse_args()
    res = parts(Path(args.spec), args.number)
    every = res.pop("qp_every")
    for name, us in res.items():
        print(f"{name:40s} {us:7.2f} us")
    print(f"(the QP runs every {every} steps)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
