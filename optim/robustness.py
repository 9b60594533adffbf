"""Where a CMRT holds: a given CMRT and the flat spline simulated at every value of one of the
spec's numbers over a range (`cmrt robustness`).

Contracts:
  * `robustness_spec(spec, path, lo, hi, steps)` is the spec with the robust block
    {vary: {path: [lo, hi]}, samples: steps} (`sim.robust`) in place of its own: the values are
    the block's evenly spaced levels (ends included), and the path, the range and every value's
    spec are checked by the spec's own rules before anything is simulated. A bad path or range
    raises `OptimError` naming the option (`--vary`, `--steps`) and the rule.
  * `run_robustness(canonical, params, executor)` evaluates the CMRT and the flat spline at
    every value as one batch of evaluation points (`optim.robust.points`: the same variant
    scenes a robust optimisation scores), results in value order, independent of the number of
    workers.
  * `holds(outcomes, values)` gives the ranges (contiguous runs of values) where the clip
    stands and its task, if it has a goal, succeeds.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from optim.errors import OptimError
from optim.executors import Executor
from optim.objective import SimObjective
from optim.outcome import EvalOutcome
from optim.robust import points
from optim.spline import flat_params
from sim.errors import SpecError
from sim.robust import variant_values
from sim.spec import CanonicalSpec, TaskSpec, parse_canonical


def robustness_spec(spec: TaskSpec, path: str, lo: float, hi: float,
                    steps: int) -> CanonicalSpec:
    """The spec whose robust variants are the values to simulate (see the module docstring)."""
    doc = spec.model_dump(mode="json")
    doc["optimize"] = {**doc["optimize"],
                       "robust": {"vary": {path: [lo, hi]}, "samples": steps}}
    try:
        return parse_canonical(doc, "--vary")
    except SpecError as err:
        msg = str(err).removeprefix("--vary: ")
        msg = re.sub(r"optimize\.robust\.samples: must be from (\d+) to (\d+) variants",
                     r"--steps: must be from \1 to \2 values", msg)
        msg = msg.replace(f"optimize.robust.vary.{path}: ", "").replace(
            "optimize.robust.vary: ", "").replace("optimize.robust: variant", "value")
        if not msg.startswith("--steps"):
            msg = f"--vary {path} {lo:g} {hi:g}: {msg}"
        raise OptimError(msg) from None


@dataclass(frozen=True)
class RobustnessRow:
    """One value: the CMRT's and the flat spline's outcomes there."""

    value: float
    cmrt: EvalOutcome
    flat: EvalOutcome

    def to_dict(self) -> dict[str, Any]:
        return {"value": self.value, "cmrt": _brief(self.cmrt), "flat": _brief(self.flat)}


def _brief(o: EvalOutcome) -> dict[str, Any]:
    return {"objective": o.objective, "fell": o.fell, "fall_time": o.fall_time,
            "fall_direction": o.fall_direction, "task_success": o.task_success,
            "error": o.error}


def run_robustness(canonical: CanonicalSpec, params: Sequence[float] | np.ndarray,
                   executor: Executor) -> list[RobustnessRow]:
    """The CMRT `params` and the flat spline at every value (see the module docstring)."""
    spec = canonical.spec
    rb = spec.optimize.robust
    assert rb is not None and len(rb.vary) == 1, "a spec from robustness_spec"
    path = rb.paths[0]
    values = [v[path] for v in variant_values(rb)]
    k = len(values)
    outs = executor.map(SimObjective(canonical),
                        points(spec, [np.asarray(params, dtype=float), flat_params(spec)]))
    return [RobustnessRow(values[i], outs[i], outs[k + i]) for i in range(k)]


def stands(o: EvalOutcome) -> bool:
    """The clip stood and its task's goal, if any, was reached."""
    return o.error is None and not o.fell and o.task_success is not False


def holds(outcomes: Sequence[EvalOutcome], values: Sequence[float]
          ) -> list[tuple[float, float]]:
    """The contiguous runs of values where `stands`, as (first, last) pairs."""
    runs: list[tuple[float, float]] = []
    start = None
    for i, o in enumerate(outcomes):
        if stands(o) and start is None:
            start = i
        if start is not None and (not stands(o) or i == len(outcomes) - 1):
            end = i if stands(o) else i - 1
            runs.append((values[start], values[end]))
            start = None
    return runs


def _cell(o: EvalOutcome) -> str:
    if o.error is not None:
        return f"{'error':<24}"
    pose = "stands" if not o.fell else f"falls {o.fall_direction or ''} {o.fall_time or 0:.3f} s"
    task = {True: "yes", False: "no", None: "-"}[o.task_success]
    return f"{pose:<24}{task:>5} {o.objective:>9.4f}"


def table(path: str, rows: Sequence[RobustnessRow]) -> str:
    """The rows as a text table and the ranges where each holds."""
    head = f"{'stand/fall':<24}{'task':>5} {'objective':>9}"
    w = max(12, len(path))
    lines = [f"{path:>{w}}  CMRT {head}  | flat spline {head}"]
    for r in rows:
        lines.append(f"{r.value:>{w}.6g}       {_cell(r.cmrt)}  |             {_cell(r.flat)}")
    values = [r.value for r in rows]
    for label, which in (("CMRT", [r.cmrt for r in rows]), ("flat spline", [r.flat for r in rows])):
        runs = holds(which, values)
        shown = ", ".join(f"{a:g}-{b:g}" if a != b else f"{a:g}" for a, b in runs) or "nowhere"
        lines.append(f"{label} holds at {path} {shown}")
    return "\n".join(lines)


__all__ = ["RobustnessRow", "holds", "robustness_spec", "run_robustness", "stands", "table"]
