"""Is the rollout loop slower than another version of it? Both in one process, runs alternated.

    git show REV:sim/rollout.py > /tmp/old_rollout.py
    .venv/bin/python -m bench.rollout_ab /tmp/old_rollout.py [SPEC.yaml ...] [--pairs 20]

The other version's `sim/rollout.py` is loaded as a module of its own beside this checkout's
`sim.rollout`; both build their Rollout from the same spec and share everything else (the
controllers, the physics, the compiled model terms), so the difference measured is the loop's.
Each pair runs both clips (no CMRT) one after the other, in alternating order, timed by
`time.process_time`; reported per spec: the lowest CPU seconds per simulated second of each,
and the median and range of new / old over the pairs. The two objectives must agree by repr
(exit 1 otherwise). Default specs: a 2 s quiet stance, examples/catch.yaml and
examples/step_push.yaml (held steps, props, stepping).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from sim.rollout import Rollout
from sim.spec import TaskSpec, load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path) -> Any:
    spec = importlib.util.spec_from_file_location("rollout_under_test", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"{path}: not a Python module")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def compare(old_rollout: Any, spec: TaskSpec, pairs: int) -> dict[str, Any]:
    """One spec's timings (see the module docstring)."""
    a, b = old_rollout.Rollout(spec), Rollout(spec)
    try:
        ea, eb = a.run(), b.run()  # also the warm-up
        times: dict[str, list[float]] = {"old": [], "new": []}
        for i in range(pairs):
            order = (("old", a), ("new", b)) if i % 2 == 0 else (("new", b), ("old", a))
            for name, sim in order:
                t0 = time.process_time()
                sim.run()
                times[name].append(time.process_time() - t0)
    finally:
        a.close()
        b.close()
    ratios = [n / o for o, n in zip(times["old"], times["new"], strict=True)]
    return {"spec": spec.name, "same_objective": repr(ea.objective) == repr(eb.objective),
            "old_cpu_per_sim_second": min(times["old"]) / ea.sim_seconds,
            "new_cpu_per_sim_second": min(times["new"]) / eb.sim_seconds,
            "new_over_old_median": statistics.median(ratios),
            "new_over_old_range": (min(ratios), max(ratios))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="the other version's sim/rollout.py")
    ap.add_argument("specs", nargs="*", type=Path)
    ap.add_argument("--pairs", type=int, default=20)
    args = ap.parse_args(argv)
    specs = ([load_spec(p) for p in args.specs] if args.specs else
             [parse_spec({"name": "quiet_stance_2s", "task": {"type": "quiet_stance"},
                          "clip": {"preparation": 0.0, "duration": 2.0, "decay": 0.0}}),
              load_spec(ROOT / "examples/catch.yaml"), load_spec(ROOT / "examples/step_push.yaml")])
    old = _load(args.old)
    ok = True
    for spec in specs:
        r = compare(old, spec, args.pairs)
        ok = ok and r["same_objective"]
        lo, hi = r["new_over_old_range"]
        print(f"{r['spec']}: old {r['old_cpu_per_sim_second']:.4f}, new "
              f"{r['new_cpu_per_sim_second']:.4f} CPU s per simulated s (lowest); new/old "
              f"median {r['new_over_old_median']:.4f} (range {lo:.3f}-{hi:.3f}); objectives "
              f"{'identical' if r['same_objective'] else 'DIFFER'}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
