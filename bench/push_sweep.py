"""Largest survived push (0.2 s on the trunk, zero CMRT) in each direction, by bisection.

Usage: .venv/bin/python bench/push_sweep.py [--lo 50] [--hi 600] [--tol 5]
Prints, per direction, the largest force (N) survived and the smallest that fell.
"""

from __future__ import annotations

import argparse
import json

from sim.rollout import Rollout
from sim.spec import parse_spec


def survives(force: float, direction: str) -> bool:
    spec = parse_spec({"name": "push_sweep",
                       "clip": {"preparation": 1.0, "duration": 0.2, "decay": 1.8},
                       "task": {"type": "push", "force": force, "direction": direction,
                                "body": "trunk"}})
    return not Rollout(spec).run().fell


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lo", type=float, default=50.0)
    ap.add_argument("--hi", type=float, default=600.0)
    ap.add_argument("--tol", type=float, default=5.0)
    args = ap.parse_args()
    out = {}
    for direction in ("forward", "backward"):
        lo, hi = args.lo, args.hi
        if not survives(lo, direction):
            out[direction] = {"largest_survived": None, "smallest_fell": lo}
            continue
        if survives(hi, direction):
            out[direction] = {"largest_survived": hi, "smallest_fell": None}
            continue
        while hi - lo > args.tol:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if survives(mid, direction) else (lo, mid)
        out[direction] = {"largest_survived": lo, "smallest_fell": hi}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
