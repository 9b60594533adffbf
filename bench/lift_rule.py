"""The heel-lift hand-over with and without a capture-point gate, on every example.

    .venv/bin/python bench/lift_rule.py [SPEC ...] [--cmrt RESULT.json] [--task KEY=VALUE ...]
                                        [--json]

The default controller loses balance when a stance heel or toe lifts FOOT_LIFT_LIMIT (3 cm,
`sim.controllers.momentum`). The candidate refinement measured here: such a lift counts only
while the CM's capture point x_cp = c_x + v_x sqrt(c_y / g) lies outside the support (beyond
the toe or the heel edge), i.e. when no CoP under the feet can bring the CM to rest over them.
It is applied without touching the controller's code: after each `act`, a "foot_lift" verdict
is withdrawn while x_cp is inside the support (the verdict is what the rollout reads, at the
same step; nothing else in the controller depends on it). Each spec (default: every
examples/*.yaml) runs with the CMRT (`--cmrt`, else none, as `cmrt simulate --zero`) under
both rules; `--task mass=1` overrides task fields (numbers). For the gated run it also prints
the highest stance heel/toe and the capture point's closest approach to the support's edges
(negative: outside), over the feet-fixed controller's steps. No assertions (an experiment:
docs/benchmarks.md, "The punch mismatch").
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

from cmrt.specfile import read_spec_file
from optim.result import OptimizationResult
from sim.controllers.momentum import MomentumController
from sim.ipm import capture_point
from sim.rollout import Rollout
from sim.spec import parse_spec

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@contextmanager
def gated_lift(seen: dict[str, float]) -> Iterator[None]:
    """Within: a heel/toe lift loses balance only with the capture point outside the support.
    `seen` collects the highest stance heel/toe ("lift", m) and the capture point's closest
    approach to the support's edges ("margin", m; < 0: outside) over the feet-fixed steps."""
    inner = MomentumController.act

    def act(self: MomentumController, obs: Any, t: float) -> Any:
        tau = inner(self, obs, t)
        lo, hi = obs.support
        xi = capture_point(obs.c, obs.cd)
        seen["lift"] = max(seen["lift"], float(obs.points[:, 1].max()))
        seen["margin"] = min(seen["margin"], xi - lo, hi - xi)
        if self.lost == "foot_lift" and lo <= xi <= hi:
            self.lost = None
        return tau

    MomentumController.act = act  # type: ignore[method-assign]
    try:
        yield
    finally:
        MomentumController.act = inner  # type: ignore[method-assign]


def run(data: dict[str, Any], cmrt: Any) -> dict[str, Any]:
    sim = Rollout(parse_spec(data))
    try:
        ev = sim.run(cmrt)
    finally:
        sim.close()
    return {"objective": ev.objective, "fell": ev.fell, "fall_time": ev.fall_time,
            "fall_reason": ev.fall_reason, "fall_direction": ev.fall_direction}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("specs", nargs="*", help="spec files (default: every examples/*.yaml)")
    ap.add_argument("--cmrt", help="a result file (cmrt optimize --out)")
    ap.add_argument("--task", nargs="*", default=[], help="KEY=VALUE task fields (numbers)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.specs] or sorted(  # not a user's character file
        p for p in EXAMPLES.glob("*.yaml") if "segments" not in yaml.safe_load(p.read_text()))
    cmrt = OptimizationResult.load(args.cmrt).spline() if args.cmrt else None
    out = []
    for path in paths:
        data = read_spec_file(path)
        for kv in args.task:
            key, value = kv.split("=", 1)
            data["task"][key] = float(value)
        default = run(data, cmrt)
        seen = {"lift": 0.0, "margin": float("inf")}
        with gated_lift(seen):
            gated = run(data, cmrt)
        out.append({"spec": data["name"], "default": default, "gated": gated, **seen})
    if args.json:
        print(json.dumps(out, indent=1))
        return 0

    def verdict(r: dict[str, Any]) -> str:
        if not r["fell"]:
            return f"stands {r['objective']:.4f}"
        return (f"fell {r['fall_direction']} {r['fall_time']:.3f} s ({r['fall_reason']}) "
                f"{r['objective']:.4f}")

    for r in out:
        same = "same" if r["default"] == r["gated"] else "MOVED"
        print(f"{r['spec']:18s} default: {verdict(r['default'])}\n{'':18s} gated:   "
              f"{verdict(r['gated'])}  [{same}]; highest heel/toe {100 * r['lift']:.1f} cm, "
              f"capture point at closest {100 * r['margin']:+.1f} cm from an edge")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
