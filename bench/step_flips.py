"""Does a push grid's outcome depend on numeric noise? Every cell of a push spec's grid run as
given and with its initial state perturbed (a root coordinate or a hinge angle moved by a tiny
amount, 1e-9 by default), cell by cell, and the cells whose outcome (survived or fell, steps
taken) differs between the two listed.

    .venv/bin/python -m bench.step_flips examples/step_push.yaml --forces 50 325 25 \
        --durations 0.4 [--dof 0] [--delta 1e-9] [--json out.json]

`--dof`: the generalised coordinate moved (0: the root's x; ROOT_DOF + j: hinge j). The spec's
own runs are untouched: the perturbation is applied to this script's `Rollout.q0` only.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml

from optim.sweep import cell_document, spec_document
from sim.rollout import Rollout
from sim.spec import parse_spec


def run_cell(doc: dict, dof: int | None, delta: float) -> dict:
    """One cell's outcome; `dof` None runs it as given, else q0[dof] += delta."""
    sim = Rollout(parse_spec(doc))
    if dof is not None:
        sim.q0[dof] += delta
    ev = sim.run(None)
    out = {"fell": bool(ev.fell), "fall_time": ev.fall_time, "objective": float(ev.objective),
           "steps": sim.controller.foot_steps, "cpu": float(ev.cpu_seconds)}
    sim.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("--forces", nargs=3, type=float, default=[50.0, 325.0, 25.0],
                    metavar=("FROM", "TO", "STEP"))
    ap.add_argument("--durations", nargs="+", type=float, default=[0.4])
    ap.add_argument("--directions", nargs="+", default=["forward", "backward"])
    ap.add_argument("--dof", type=int, default=0)
    ap.add_argument("--delta", type=float, default=1e-9)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    base = spec_document(parse_spec(yaml.safe_load(Path(args.spec).read_text())))
    lo, hi, step = args.forces
    forces = [float(f) for f in np.arange(lo, hi + 0.5 * step, step)]
    rows = []
    t0 = time.process_time()
    for direction in args.directions:
        for d in args.durations:
            for f in forces:
                doc = cell_document(base, f, d, direction)
                a = run_cell(doc, None, 0.0)
                b = run_cell(doc, args.dof, args.delta)
                flip = a["fell"] != b["fell"] or a["steps"] != b["steps"]
                rows.append({"force": f, "duration": d, "direction": direction,
                             "base": a, "perturbed": b, "flip": flip})
                print(f"{direction:8s} {d:.2f} s {f:5.0f} N  "
                      f"{'fell ' if a['fell'] else 'stood'} {a['steps']} steps {a['objective']:.4f}"
                      f" | {'fell ' if b['fell'] else 'stood'} {b['steps']} steps "
                      f"{b['objective']:.4f} {'FLIP' if flip else ''}", flush=True)
    for direction in args.directions:
        cells = [r for r in rows if r["direction"] == direction]
        print(f"{direction}: survived {sum(not r['base']['fell'] for r in cells)} of "
              f"{len(cells)} (perturbed {sum(not r['perturbed']['fell'] for r in cells)}); "
              f"flips at {[r['force'] for r in cells if r['flip']]} N")
    print(f"CPU {time.process_time() - t0:.1f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
