"""Where a control step's time goes: one clip's loop under cProfile, grouped by part.

    .venv/bin/python bench/step_profile.py [SPEC ...] [--runs 3] [--json]

Each spec (default: the quiet stance, catch, punch and domino) is built once (`sim.rollout.
Rollout`), run once unmeasured, then `--runs` times without the profiler (CPU per step) and
`--runs` times under cProfile. The profile's own time per function (tottime) is grouped into
the parts of a step: ODE's world step; contact handling (the collision callback, making the
contact joints, reading their forces, clearing them); reading the state; the model terms (the
compiled per-step calls); the QP (the momentum controller's solve, 60 Hz); the controller's
other work; the task's hooks; recording; the loop itself (`_Clip`'s phases, their own lines); the
rest of `sim.physics` and `sim.prop_bodies` (applying torques, the divergence check,
reprojection). Shares are of the
profiled total; the profiler's per-call cost inflates the parts made of many small Python
calls, so read them as an upper bound for those and a lower one for ODE. No assertions.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["examples/quiet_stance.yaml", "examples/catch.yaml", "examples/punch.yaml",
           "examples/domino.yaml"]

#: Part of a step by (file suffix, function name); first match wins, "" matches any function.
PARTS = [
    ("world step (ODE)", [("~", "<method 'step' of 'ode.World' objects>")]),
    ("contacts", [("sim/physics.py", "make_contacts"), ("sim/physics.py", "contact_forces"),
                  ("sim/physics.py", "_near"), ("weakref.py", ""), ("~", "'getBody'"),
                  ("sim/physics.py", "clear_contacts"), ("~", "ode.Contact"),
                  ("~", "ode.JointGroup"), ("~", "ode.ContactJoint"), ("~", "'setFeedback'"),
                  ("~", "'getFeedback'"), ("~", "'attach'"), ("~", "ode.collide"),
                  ("~", "'collide'")]),
    ("state read", [("sim/physics.py", "read_state"), ("~", "'getAngle'"),
                    ("~", "'getAngleRate'"), ("~", "'getPosition'"),
                    ("~", "'getLinearVel'"), ("~", "'getQuaternion'"),
                    ("~", "'getAngularVel'")]),
    ("model terms (compiled)", [("sim/dynamics.py", "")]),
    ("QP (momentum solve)", [("sim/controllers/momentum.py", "solve"), ("numpy/linalg", ""),
                             ("scipy", "")]),
    ("controller, other", [("sim/controllers/", ""), ("sim/trajectory.py", "")]),
    ("task hooks", [("sim/tasks/", "")]),
    ("recording", [("sim/recording.py", "")]),
    ("loop (rollout's own lines)", [("sim/rollout.py", "")]),
    ("physics wrapper (torques, checks)", [("sim/physics.py", ""), ("sim/prop_bodies.py", "")]),
]


def _part(filename: str, func: str) -> str:
    for name, rules in PARTS:
        for suffix, fn in rules:
            if suffix == "~":
                if fn in func:
                    return name
            elif suffix in filename and (not fn or fn == func):
                return name
    return "other"


def profile(path: str, runs: int) -> dict:
    from sim.rollout import Rollout
    from sim.spec import load_spec

    r = Rollout(load_spec(ROOT / path))
    r.run()
    c0 = time.process_time()
    for _ in range(runs):
        r.run()
    per_step_us = (time.process_time() - c0) / runs / r.steps * 1e6
    pr = cProfile.Profile()
    pr.enable()
    for _ in range(runs):
        r.run()
    pr.disable()
    st = pstats.Stats(pr)
    parts: dict[str, float] = {}
    total = 0.0
    for (filename, _line, func), (_cc, _nc, tt, _ct, _callers) in st.stats.items():
        parts[_part(filename, func)] = parts.get(_part(filename, func), 0.0) + tt
        total += tt
    r.close()
    return {"spec": path, "steps": r.steps, "cpu_us_per_step": per_step_us,
            "shares": {k: v / total for k, v in sorted(parts.items(), key=lambda kv: -kv[1])}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("specs", nargs="*", default=DEFAULT)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = [profile(p, args.runs) for p in args.specs]
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    names = [n for n, _ in PARTS] + ["other"]
    print("| spec | us per step | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for r in rows:
        print(f"| {Path(r['spec']).stem} | {r['cpu_us_per_step']:.0f} | "
              + " | ".join(f"{100 * r['shares'].get(n, 0.0):.0f} %" for n in names) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
