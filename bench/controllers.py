"""The balance controllers side by side: momentum QP, world-space PD, parent-space PD.

    .venv/bin/python bench/controllers.py [--tol 2] [--hi 400] [--workers 2] [--json OUT]

For each controller (and each PD servo with its k1, k2 scaled x0.5, x1, x2, the paper's
gain-insensitivity test) it measures, with no CMRT:
  * quiet stance, 10 s: the objective (CP error norm, m) or the fall time;
  * the largest 0.2 s push on the trunk survived forward and backward: bisection on the force
    (N) between 0 and --hi to within --tol (a clip of examples/push.yaml: 1 s preparation,
    0.2 s push, 1.8 s decay); "falls unpushed" when the 3 s clip falls with a 0.01 N push;
  * the slow bend (examples/slow_bend.yaml) and the fast bend (examples/fast_bend.yaml): the
    objective, or the fall time. The momentum rows keep the examples' gain schedules (the
    fast bend's, paper Table 3); the PD servos take none.
and prints one markdown table. No assertions: an experiment (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import time
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import yaml

from sim import evaluate, parse_spec

ROOT = Path(__file__).resolve().parents[1]

EXAMPLES = ROOT / "examples"
QUIET_SECONDS = 10.0
SCALES = (0.5, 1.0, 2.0)
UNPUSHED = 0.01  # N, the push clip's force when checking that it stands without a push


def _example(name: str) -> dict[str, Any]:
    return yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text())


def _spec(name: str, controller: dict[str, Any], **changes: Any) -> Any:
    d = _example(name)
    d.update(changes)
    d["controller"] = controller
    if controller.get("type", "momentum") != "momentum":
        d.pop("schedule", None)  # gain schedules are the momentum controller's
    return parse_spec(d, name)


def _outcome(spec: Any) -> tuple[float, bool, float | None]:
    e = evaluate(spec)
    return e.objective, e.fell, e.fall_time


def _survives_push(controller: dict[str, Any], force: float, direction: str) -> bool:
    task = {"type": "push", "force": force, "direction": direction, "body": "trunk"}
    return not _outcome(_spec("push", controller, task=task))[1]


def largest_push(controller: dict[str, Any], direction: str, hi: float, tol: float
                 ) -> tuple[float, float | None]:
    """(largest force survived, smallest force that fell; None if --hi survived). (0, 0):
    the clip falls with a negligible push (UNPUSHED N), so no largest push is defined (a
    push against the drift would "help", and bisection assumes falling grows with force)."""
    if not _survives_push(controller, UNPUSHED, direction):
        return 0.0, 0.0
    if _survives_push(controller, hi, direction):
        return hi, None
    lo = UNPUSHED
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if _survives_push(controller, mid, direction):
            lo = mid
        else:
            hi = mid
    return lo, hi


def measure(job: tuple[str, dict[str, Any], float, float]) -> dict[str, Any]:
    """Every measurement of one controller block."""
    label, controller, hi, tol = job
    cpu0 = time.process_time()
    clip = {"preparation": 0.0, "duration": QUIET_SECONDS, "decay": 0.0}
    row: dict[str, Any] = {"label": label, "controller": controller}
    row["quiet"] = _outcome(_spec("quiet_stance", controller, clip=clip))
    row["slow_bend"] = _outcome(_spec("slow_bend", controller))
    row["fast_bend"] = _outcome(_spec("fast_bend", controller))
    for direction in ("forward", "backward"):
        row[f"push_{direction}"] = largest_push(controller, direction, hi, tol)
    row["cpu_seconds"] = time.process_time() - cpu0
    return row


def _fmt_outcome(o: tuple[float, bool, float | None]) -> str:
    objective, fell, t = o
    return f"falls at {t:.2f} s" if fell else f"{objective:.4f}"


def _fmt_push(p: tuple[float, float | None]) -> str:
    lo, hi = p
    if hi == 0.0:
        return "falls unpushed"
    return f">= {lo:.0f} N" if hi is None else f"{lo:.1f} N ({hi:.1f} falls)"


def jobs(hi: float, tol: float) -> list[tuple[str, dict[str, Any], float, float]]:
    out: list[tuple[str, dict[str, Any], float, float]] = [("momentum", {"type": "momentum"},
                                                             hi, tol)]
    for kind in ("pd_world", "pd_parent"):
        for s in SCALES:
            block: dict[str, Any] = {"type": kind}
            if s != 1.0:
                block.update(k1=100.0 * s, k2=10.0 * s)
            out.append((f"{kind} x{s:g}", block, hi, tol))
    out.append(("pd_world person x1", {"type": "pd_world", "root": "person"}, hi, tol))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tol", type=float, default=2.0, help="push bisection tolerance (N)")
    ap.add_argument("--hi", type=float, default=400.0, help="largest push tried (N)")
    ap.add_argument("--workers", type=int, default=2, help="processes (at most 2 here)")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON")
    args = ap.parse_args(argv)
    t0 = time.time()
    todo = jobs(args.hi, args.tol)
    if args.workers > 1:
        with get_context("spawn").Pool(args.workers) as pool:
            rows = pool.map(measure, todo, chunksize=1)
    else:
        rows = [measure(j) for j in todo]
    print("| controller (k1 s^-2, k2 s^-1) | quiet stance 10 s | push 0.2 s forward | "
          "push 0.2 s backward | slow bend | fast bend |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        c = r["controller"]
        gains = (f" ({c.get('k1', 100.0):g}, {c.get('k2', 10.0):g})"
                 if c["type"] != "momentum" else "")
        print(f"| {r['label']}{gains} | {_fmt_outcome(r['quiet'])} | "
              f"{_fmt_push(r['push_forward'])} | {_fmt_push(r['push_backward'])} | "
              f"{_fmt_outcome(r['slow_bend'])} | {_fmt_outcome(r['fast_bend'])} |")
    cpu = sum(r["cpu_seconds"] for r in rows)
    print(f"\n{len(rows)} controllers, {cpu:.0f} s CPU, {time.time() - t0:.0f} s wall "
          f"({args.workers} workers)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
