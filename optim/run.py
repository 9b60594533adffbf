"""The optimisation loop: CMA-ES ask/tell over a spec's CMRT, with checkpoints and resume.

`optimize(spec, executor, *, seed, ...)`:
  1. Start (`initial_point`): x0 (warm start, full params) or the flat spline; with a `basis`
     the search is over the basis' box [0, 1]^k (x0 is projected into it; default the box
     centre) and candidates are decoded to full params with the target's duration pinned
     (optim.pca).
  2. Each generation: ask, evaluate every candidate through `executor.map(objective, ...)`
     (generation barrier), tell, then atomically write the checkpoint (temp file, fsync,
     os.replace), then call `progress(stats)`; returning True from it stops with "cancelled".
     If every candidate of a generation failed with an error, EvaluationError is raised.
  3. Stop when a rule of optim.cmaes fires (spec.optimize: threshold, slow convergence,
     max evaluations) or pycma's own termination.
  4. Evaluate the flat spline (the no-CMRT baseline) and the best params, and build the
     `OptimizationResult`.
Resume: with `resume=True` and an existing checkpoint, the optimizer state is restored and the
loop continues; the result equals that of an uninterrupted run (wall time aside). The
checkpoint must belong to the same spec, seed, basis and search dimension (CheckpointError
otherwise); `resume=True` with no checkpoint file starts afresh. Checkpoints are pickles:
read them only from trusted storage.
"""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from optim._io import atomic_write_bytes
from optim.cmaes import CmaOptimizer, GenerationStats, StopRules
from optim.errors import CheckpointError, EvaluationError
from optim.executors import EvalOutcome, Executor
from optim.objective import SimObjective, spec_json
from optim.result import OptimizationResult
from optim.spline import check_params, flat_params

if TYPE_CHECKING:
    from optim.pca import Basis
    from sim.spec import TaskSpec

CHECKPOINT_FORMAT = "cmrt-checkpoint/1"
#: Stop rule recorded when the progress callback asks to stop.
CANCELLED = "cancelled"

Progress = Callable[[GenerationStats], "bool | None"]
Objective = Callable[[np.ndarray], "EvalOutcome | float"]


def _checkpoint_meta(spec: TaskSpec, seed: int, basis: Basis | None, dim: int) -> dict[str, Any]:
    return {
        "spec_json": spec_json(spec),
        "seed": int(seed),
        "basis_id": None if basis is None else basis.id,
        "dim": int(dim),
    }


def save_checkpoint(
    path: Path, opt: CmaOptimizer, meta: dict[str, Any], wall_seconds: float
) -> None:
    """Atomically write the optimizer state, its history and the run identity to `path`."""
    payload = {
        "format": CHECKPOINT_FORMAT,
        **meta,
        "optimizer": opt.dumps(),
        "history": [h.to_dict() for h in opt.history],
        "wall_seconds": float(wall_seconds),
    }
    atomic_write_bytes(path, pickle.dumps(payload, protocol=4))


def load_checkpoint(path: Path) -> dict[str, Any]:
    """The checkpoint payload (see `save_checkpoint`); CheckpointError if unreadable."""
    try:
        payload = pickle.loads(Path(path).read_bytes())
    except OSError as err:
        raise CheckpointError(f"{path}: cannot read checkpoint ({err.strerror})") from None
    except Exception as err:  # noqa: BLE001 - truncated / foreign file
        raise CheckpointError(f"{path}: not a readable checkpoint ({err})") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a CMRT checkpoint (format tag missing or wrong)")
    return payload


def _resume(path: Path, meta: dict[str, Any]) -> tuple[CmaOptimizer, float]:
    payload = load_checkpoint(path)
    for key, what in (
        ("spec_json", "spec"),
        ("seed", "seed"),
        ("basis_id", "basis"),
        ("dim", "search dimension"),
    ):
        if payload.get(key) != meta[key]:
            raise CheckpointError(
                f"{path}: checkpoint is for a different {what} "
                f"({payload.get(key)!r:.80} != {meta[key]!r:.80}); delete it or drop --resume"
            )
    return CmaOptimizer.loads(payload["optimizer"]), float(payload.get("wall_seconds", 0.0))


def initial_point(
    spec: TaskSpec,
    *,
    x0: Sequence[float] | np.ndarray | None = None,
    basis: Basis | None = None,
) -> np.ndarray:
    """CMA-ES start in the search space used by `optimize` (use it in other drivers too).

    Full space: x0 (checked, clipped into [0, 1]) or the flat spline. Reduced space: x0
    projected into the basis box (`Basis.encode` at the spec's duration), or the box centre
    (u = 0.5, about the family mean) when no x0 is given. Raises BasisError if the basis does
    not fit the spec.
    """
    if basis is None:
        return flat_params(spec) if x0 is None else check_params(spec, x0)
    basis.check_spec(spec)
    if x0 is None:
        return np.full(basis.k, 0.5)
    return basis.encode(check_params(spec, x0), spec.clip.duration)


def optimize(
    spec: TaskSpec,
    executor: Executor,
    *,
    seed: int,
    x0: Sequence[float] | np.ndarray | None = None,
    checkpoint: Path | str | None = None,
    resume: bool = False,
    progress: Progress | None = None,
    basis: Basis | None = None,
    objective: Objective | None = None,
) -> OptimizationResult:
    """Optimise the CMRT of `spec` (see module docstring).

    objective: full-params callable evaluated through `executor` (default SimObjective(spec));
    any picklable `params -> EvalOutcome | float` works (tests, benchmarks).
    """
    t0 = time.perf_counter()
    fn: Objective = objective if objective is not None else SimObjective(spec)
    ckpt = None if checkpoint is None else Path(checkpoint)
    start = initial_point(spec, x0=x0, basis=basis)
    if basis is not None:
        duration = spec.clip.duration
        dim = basis.k

        def to_full(x: np.ndarray) -> np.ndarray:
            return basis.decode(x, duration)

    else:
        dim = spec.cmrt_dimension

        def to_full(x: np.ndarray) -> np.ndarray:
            return np.clip(np.asarray(x, dtype=float), 0.0, 1.0)

    meta = _checkpoint_meta(spec, seed, basis, dim)
    opt: CmaOptimizer | None = None
    wall_before = 0.0
    if resume and ckpt is not None and ckpt.exists():
        opt, wall_before = _resume(ckpt, meta)
    if opt is None:
        opt = CmaOptimizer(
            dim,
            seed=seed,
            x0=start,
            sigma0=spec.optimize.sigma0,
            popsize=spec.optimize.popsize,
            rules=StopRules.from_config(spec.optimize),
        )

    stop_rule = opt.stop()
    while stop_rule is None:
        xs = opt.ask()
        outs = executor.map(fn, [to_full(x) for x in xs])
        if len(outs) != len(xs):
            raise EvaluationError(
                f"executor returned {len(outs)} outcomes for {len(xs)} candidates"
            )
        if all(o.error is not None for o in outs):
            raise EvaluationError(
                f"every candidate of generation {opt.iterations + 1} failed; first error: "
                f"{outs[0].error}"
            )
        stats = opt.tell(xs, [o.objective for o in outs])
        if ckpt is not None:
            save_checkpoint(ckpt, opt, meta, wall_before + time.perf_counter() - t0)
        if progress is not None and progress(stats) is True:
            stop_rule = CANCELLED
            break
        stop_rule = opt.stop()

    best_x = opt.best_x
    assert best_x is not None  # at least one generation was told
    best_full = to_full(best_x)
    base_out, best_out = executor.map(fn, [flat_params(spec), best_full])
    for label, out in (("baseline (flat spline)", base_out), ("best CMRT", best_out)):
        if out.error is not None:
            raise EvaluationError(f"final evaluation of the {label} failed: {out.error}")

    return OptimizationResult.build(
        spec,
        best_full,
        objective=best_out.objective,
        fell=best_out.fell,
        baseline_objective=base_out.objective,
        baseline_fell=base_out.fell,
        evaluations=opt.evaluations,
        iterations=opt.iterations,
        stop_rule=stop_rule,
        wall_seconds=wall_before + time.perf_counter() - t0,
        seed=seed,
        history=[h.to_dict() for h in opt.history],
        basis_id=None if basis is None else basis.id,
        reduced_params=None if basis is None else best_x,
    )


__all__ = [
    "CANCELLED",
    "CHECKPOINT_FORMAT",
    "initial_point",
    "load_checkpoint",
    "optimize",
    "save_checkpoint",
]
