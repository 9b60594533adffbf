"""A robust spec's candidates as evaluation points, and their outcomes aggregated back.

A spec with `optimize.robust` (`sim.robust`) scores each candidate at its K scene variants.
Every variant is an evaluation of its own, so the executors (the command line's pool, the
service's local pool, Celery workers) spread K x popsize clips per generation:
  * `points(spec, candidates)`: each candidate's params followed by one more entry, the
    variant index k (0 .. K-1, exact in a float), in candidate-major order;
  * `split_point(spec, point)`: (params, k) of an evaluation point, (params, None) for plain
    params (the spec's own scene); `optim.objective.SimObjective` simulates variant k;
  * `aggregate(spec, outcomes)`: one outcome per candidate from its K: the objective is the
    mean (fsum / K) or the worst of the K, fell if any variant fell, the task succeeded if it
    did in every variant; any error makes the candidate failed (FAILED_OBJECTIVE).
A generation's rank cut (`optim.rankcut`) ranks candidates, not variants: it is off for a
robust spec (`cut_allowed`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from optim.outcome import FAILED_OBJECTIVE, EvalOutcome

if TYPE_CHECKING:
    from sim.spec import TaskSpec


def samples(spec: TaskSpec) -> int:
    """K: the variants per candidate (1: a spec without a robust block)."""
    robust = spec.optimize.robust
    return 1 if robust is None else robust.samples


def cut_allowed(spec: TaskSpec) -> bool:
    """Whether a generation's certain last may be cut (`optim.rankcut`): not for a robust spec,
    whose batch entries are variants of candidates."""
    return spec.optimize.robust is None


def points(spec: TaskSpec, candidates: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The evaluation points of `candidates` (themselves for a spec without robust block)."""
    k = samples(spec)
    if spec.optimize.robust is None:
        return [np.asarray(c, dtype=float) for c in candidates]
    return [np.append(np.asarray(c, dtype=float), float(i)) for c in candidates
            for i in range(k)]


def split_point(spec: TaskSpec, point: Sequence[float] | np.ndarray
                ) -> tuple[np.ndarray, int | None]:
    """(params, variant index) of an evaluation point; (params, None) for plain params.
    ValueError for a variant index that is not one of the spec's."""
    p = np.asarray(point, dtype=float)
    robust = spec.optimize.robust
    if robust is None or p.shape != (spec.cmrt_dimension + 1,):
        return p, None
    k = float(p[-1])
    if not (k.is_integer() and 0 <= k < robust.samples):
        raise ValueError(f"variant index {k!r} is not one of the spec's {robust.samples}")
    return p[:-1], int(k)


def combine(robust: Any, outs: Sequence[EvalOutcome]) -> EvalOutcome:
    """One candidate's outcome from its variants' (see the module docstring)."""
    cpu = math.fsum(o.cpu_seconds for o in outs)
    sim = math.fsum(o.sim_seconds for o in outs)
    failed = next((o for o in outs if o.error is not None), None)
    if failed is not None:
        return EvalOutcome(FAILED_OBJECTIVE, cpu_seconds=cpu, sim_seconds=sim,
                           error=failed.error)
    values = [o.objective for o in outs]
    objective = math.fsum(values) / len(values) if robust.aggregate == "mean" else max(values)
    fallen = next((o for o in outs if o.fell), None)
    verdicts = [o.task_success for o in outs if o.task_success is not None]
    return EvalOutcome(
        objective=objective, fell=fallen is not None, cpu_seconds=cpu, sim_seconds=sim,
        fall_time=None if fallen is None else fallen.fall_time,
        fall_direction=None if fallen is None else fallen.fall_direction,
        task_success=all(verdicts) if verdicts else None,
    )


def aggregate(spec: TaskSpec, outcomes: Sequence[EvalOutcome]) -> list[EvalOutcome]:
    """One outcome per candidate from the outcomes of `points(spec, candidates)`."""
    robust = spec.optimize.robust
    if robust is None:
        return list(outcomes)
    k = robust.samples
    return [combine(robust, outcomes[i:i + k]) for i in range(0, len(outcomes), k)]


def variant_record(values: dict[str, float], out: EvalOutcome) -> dict[str, Any]:
    """One variant's outcome as a result document records it."""
    return {"values": dict(values), "objective": float(out.objective), "fell": bool(out.fell),
            "fall_time": out.fall_time, "fall_direction": out.fall_direction,
            "task_success": out.task_success}


def robust_document(spec: TaskSpec, best: Sequence[EvalOutcome],
                    flat: Sequence[EvalOutcome]) -> dict[str, Any] | None:
    """The result's `robust` block: the range optimised for and each variant's outcome of the
    best CMRT and of the flat spline (None for a spec without robust block)."""
    from sim.robust import variant_values

    rb = spec.optimize.robust
    if rb is None:
        return None
    values = variant_values(rb)
    return {"vary": {p: list(rb.vary[p]) for p in rb.paths}, "samples": rb.samples,
            "aggregate": rb.aggregate,
            "variants": [variant_record(v, o) for v, o in zip(values, best, strict=True)],
            "baseline_variants": [variant_record(v, o) for v, o in zip(values, flat,
                                                                         strict=True)]}


__all__ = ["aggregate", "combine", "cut_allowed", "points", "robust_document", "samples",
           "split_point", "variant_record"]
