"""Does the product still compute the same thing? Every example's objectives, recorded or checked.

    .venv/bin/python -m bench.objective_identity record BASELINE.json [EXAMPLE.yaml ...]
    .venv/bin/python -m bench.objective_identity check BASELINE.json [EXAMPLE.yaml ...]

For every spec (default: every file in examples/) it runs
  * `cmrt simulate SPEC --zero --json` (the command line, in a child process), and
  * two fixed CMRTs through `optim.objective.evaluate_params`: every parameter 0.4, and every
    parameter 0.6, plus the 0.4 CMRT again with traces on (the recording and the fall
    controller's continuation), whose traces and frames are summarised by a SHA-256 of their
    JSON;
and keeps `repr` of every number of the outcome (objective, fall time, error norms, steps, ...)
but not CPU or wall times. `record` writes them; `check` compares and exits 1 naming every
field that differs (exit 0: identical by `repr`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
#: Fields of an outcome that measure the machine, not the physics.
TIMES = ("cpu_seconds", "wall_seconds")
#: The fixed CMRTs: every parameter in [0, 1] set to this value.
FIXED = (0.4, 0.6)


def _reprs(d: dict[str, Any]) -> dict[str, str]:
    return {k: repr(v) for k, v in d.items() if k not in TIMES and k not in ("traces", "frames")}


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()


def measure(path: Path) -> dict[str, Any]:
    """The outcomes of one spec (see the module docstring)."""
    from optim.objective import evaluate_params
    from sim import load_spec

    cli = [str(Path(sys.executable).with_name("cmrt")), "simulate", str(path), "--zero", "--json"]
    zero = json.loads(subprocess.run(cli, check=True, capture_output=True, text=True).stdout)
    out: dict[str, Any] = {"zero_cli": _reprs(zero)}
    spec = load_spec(path)
    for v in FIXED:
        ev = evaluate_params(spec, [v] * spec.cmrt_dimension)
        out[f"all_{v}"] = _reprs(ev.to_dict())
    ev = evaluate_params(spec, [FIXED[0]] * spec.cmrt_dimension, traces=True)
    full = ev.to_dict(include_traces=True)
    traced = _reprs(full)
    traced["traces_sha256"] = _digest(full.get("traces"))
    traced["frames_sha256"] = _digest(full.get("frames"))
    out[f"all_{FIXED[0]}_traces"] = traced
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("record", "check"))
    ap.add_argument("baseline", type=Path)
    ap.add_argument("specs", nargs="*", type=Path,
                    help="spec files (default: every examples/*.yaml)")
    args = ap.parse_args(argv)
    specs = args.specs or sorted(  # the specs, not a user's character file beside them
        p for p in (ROOT / "examples").glob("*.yaml") if b"\nsegments:" not in p.read_bytes())
    if args.mode == "record":
        result = {}
        for p in specs:
            result[p.name] = measure(p)
            print(f"recorded {p.name}: {result[p.name]['zero_cli']['objective']}", flush=True)
        args.baseline.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        return 0
    baseline = json.loads(args.baseline.read_text())
    diffs = 0
    for p in specs:
        if p.name not in baseline:
            print(f"{p.name}: not in {args.baseline}")
            diffs += 1
            continue
        got, want = measure(p), baseline[p.name]
        bad = [(run, k, want[run].get(k), got.get(run, {}).get(k))
               for run in want for k in want[run] if got.get(run, {}).get(k) != want[run][k]]
        for run, k, w, g in bad:
            print(f"{p.name} {run}.{k}: {w} -> {g}")
        diffs += len(bad)
        print(f"{p.name}: {'identical' if not bad else f'{len(bad)} differ'}", flush=True)
    print(f"{len(specs)} specs, {diffs} differences")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
