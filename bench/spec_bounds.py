"""Every range a spec states, at both ends, simulated: the ranges must be ones ODE can run.

    .venv/bin/python bench/spec_bounds.py [--examples catch domino ...] [--blocks task controller
        character] [--jobs 1] [--out results/spec_bounds.json]

For one example of each task and controller type (default) and every number of its `task`,
`controller` and `character` blocks (`sim.spec.numeric_fields`: the fields it sets and the
optional ones it leaves out), the spec is set to the field's lowest and highest allowed value,
one field at a time, and simulated once with the zero CMRT in a forked child process, so that
an abort inside ODE (`dMassCheck`, `dxNormalize4`: exit status -6) is seen as such and the
sweep goes on. Each case ends as one of: `ran` (objective, fell or not), `failed` (a
simulation error the service reports as a failed evaluation: divergence, a non-finite
controller), `refused` (a rule across fields refuses that end with this example's other
values, e.g. a chain too short for the box distance), `ERROR` (another exception: the scene
cannot be built from a valid spec, a range to narrow) or `DIED` (the process died: a range to
narrow). Prints one line per case and the counts; exits 1 if any case died or erred.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time
from pathlib import Path
from typing import Any

from sim.errors import SimError, SpecError
from sim.spec import load_spec, numeric_fields, parse_spec

ROOT = Path(__file__).resolve().parents[1]

#: One example per task type and controller type.
DEFAULT_EXAMPLES = ("catch", "domino", "fast_bend", "fast_bend_pd_world", "lion_dodge",
                    "lion_hit", "punch", "push", "quiet_stance", "sequence", "step_push",
                    "sumo_pull")
#: Longest a case may take (s) before it counts as hung.
CASE_SECONDS = 300.0


def _with(data: dict[str, Any], path: tuple[str | int, ...], value: Any) -> dict[str, Any]:
    out = json.loads(json.dumps(data))
    node: Any = out
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return out


def _simulate(data: dict[str, Any], conn: Any) -> None:
    from sim import evaluate

    try:
        e = evaluate(parse_spec(data, "case"))
        conn.send({"outcome": "ran", "objective": e.objective, "fell": e.fell})
    except SimError as err:
        conn.send({"outcome": "failed", "error": str(err)[:200]})
    except Exception as err:  # noqa: BLE001 - a valid spec the simulator cannot build: a bug
        conn.send({"outcome": "ERROR", "error": f"{type(err).__name__}: {str(err)[:200]}"})
    conn.close()


def run_case(data: dict[str, Any]) -> dict[str, Any]:
    """Simulate `data` (a valid spec) in a forked child; its outcome or how it died."""
    parent, child = mp.Pipe(duplex=False)
    proc = mp.get_context("fork").Process(target=_simulate, args=(data, child))
    t0 = time.monotonic()
    proc.start()
    child.close()
    result = None
    if parent.poll(CASE_SECONDS):
        try:
            result = parent.recv()
        except EOFError:  # the child died before sending anything
            result = None
    proc.join(timeout=5)
    if proc.is_alive():
        proc.kill()
        proc.join()
    if result is None:
        result = {"outcome": "DIED", "exitcode": proc.exitcode}
    result["seconds"] = round(time.monotonic() - t0, 2)
    return result


def cases(examples: list[str], blocks: set[str]) -> list[tuple[str, str, str, float,
                                                                 dict[str, Any]]]:
    out = []
    for name in examples:
        spec = load_spec(ROOT / "examples" / f"{name}.yaml")
        data = spec.model_dump(mode="json")
        for f in numeric_fields(spec):
            if f.path[0] not in blocks:
                continue
            for end, value in (("lo", f.lo), ("hi", f.hi)):
                v: float | int = int(value) if f.integer else value
                out.append((name, f.name, end, v, _with(data, f.path, v)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", nargs="+", default=list(DEFAULT_EXAMPLES))
    ap.add_argument("--blocks", nargs="+", default=["task", "controller", "character"])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "spec_bounds.json")
    args = ap.parse_args(argv)
    rows = []
    counts: dict[str, int] = {}
    t0 = time.monotonic()
    for example, field, end, value, data in cases(args.examples, set(args.blocks)):
        try:
            parse_spec(data, "case")
        except SpecError as err:
            result = {"outcome": "refused", "error": str(err).split(": ", 1)[1][:200]}
        else:
            result = run_case(data)
        counts[result["outcome"]] = counts.get(result["outcome"], 0) + 1
        rows.append({"example": example, "field": field, "end": end, "value": value, **result})
        detail = (f"objective {result['objective']:.4g} fell {result['fell']}"
                  if result["outcome"] == "ran" else result.get("error", result.get("exitcode")))
        print(f"{example:20s} {field:34s} {end} {value!r:>10}  {result['outcome']:8s} {detail}",
              flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"counts": counts, "cases": rows}, indent=1))
    print(f"{len(rows)} cases in {time.monotonic() - t0:.0f} s: "
          + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return 1 if counts.get("DIED") or counts.get("ERROR") else 0


if __name__ == "__main__":
    sys.exit(main())
