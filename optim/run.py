"""`cmrt optimize`'s run: the shared loop of `optim.loop` with a checkpoint file and resume.

`optimize(spec, executor, *, seed, ...)` (the steps are `optim.loop`'s, written once):
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
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from optim import robust
from optim._io import atomic_write_bytes
from optim.cmaes import CmaOptimizer, GenerationStats
from optim.errors import CheckpointError
from optim.executors import EvalOutcome, Executor
from optim.loop import (
    CANCELLED,
    FINAL_GENERATION,
    FinalEvaluation,
    SearchSpace,
    final_evaluation,
    new_optimizer,
    run_generations,
)
from optim.objective import SimObjective
from optim.outcome import Objective
from optim.result import OptimizationResult
from sim.spec import CanonicalSpec, TaskSpec, canonical_spec

if TYPE_CHECKING:
    from optim.pca import Basis

CHECKPOINT_FORMAT = "cmrt-checkpoint/1"

Progress = Callable[[GenerationStats], "bool | None"]


def _checkpoint_meta(spec: CanonicalSpec, seed: int, basis: Basis | None, dim: int
                     ) -> dict[str, Any]:
    return {
        "spec_json": spec.text,
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
        "history": [asdict(h) for h in opt.history],
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
    """CMA-ES start in the search space used by `optimize` (`SearchSpace.of(...).start`)."""
    return SearchSpace.of(spec, basis, x0).start


class BatchEvaluator:
    """`CandidateEvaluator` over an optim `Executor`: `executor.map(objective, candidates)`.

    cut_margin: not None lets a generation's certain last stop early (`optim.rankcut`; the
    run stays identical); the final evaluation is never cut."""

    def __init__(self, executor: Executor, objective: Objective,
                 cut_margin: float | None = None) -> None:
        self.executor, self.objective = executor, objective
        self.cut_margin = cut_margin

    def evaluate(self, generation: int, candidates: Sequence[np.ndarray]) -> list[EvalOutcome]:
        if self.cut_margin is None or generation == FINAL_GENERATION:
            return self.executor.map(self.objective, list(candidates))
        return self.executor.map(self.objective, list(candidates), cut_margin=self.cut_margin)


class CheckpointFile:
    """`RunState` in a checkpoint file (atomic pickle; see the module docstring)."""

    def __init__(self, path: Path, meta: dict[str, Any], *, resume: bool, t0: float) -> None:
        self.path, self.meta, self.resume, self.t0 = path, meta, resume, t0
        self.wall_before = 0.0

    def restore(self) -> CmaOptimizer | None:
        if not (self.resume and self.path.exists()):
            return None
        opt, self.wall_before = _resume(self.path, self.meta)
        return opt

    def save(self, opt: CmaOptimizer, generation: int, stats: GenerationStats,
             candidates: Sequence[np.ndarray], wall_seconds: float) -> None:
        save_checkpoint(self.path, opt, self.meta,
                        self.wall_before + time.perf_counter() - self.t0)


def optimize(
    spec: TaskSpec | CanonicalSpec,
    executor: Executor,
    *,
    seed: int,
    x0: Sequence[float] | np.ndarray | None = None,
    checkpoint: Path | str | None = None,
    resume: bool = False,
    progress: Progress | None = None,
    basis: Basis | None = None,
    objective: Objective | None = None,
    cut: bool = True,
) -> OptimizationResult:
    """Optimise the CMRT of `spec` (see module docstring). A TaskSpec is canonicalised here,
    once (the command line's boundary); the pool's processes get it by hash and text.

    objective: full-params callable evaluated through `executor` (default SimObjective(spec));
    any picklable `params -> EvalOutcome | float` works (tests, benchmarks).
    cut: stop each generation's certain last early (`optim.rankcut`): the same run (every
    generation's mean, sigma, ranking, stop rule, result) in fewer simulated seconds; only
    the history's `worst` may then be a lower bound.
    """
    t0 = time.perf_counter()
    canonical = spec if isinstance(spec, CanonicalSpec) else canonical_spec(spec)
    spec = canonical.spec
    fn: Objective = objective if objective is not None else SimObjective(canonical)
    space = SearchSpace.of(spec, basis, x0)
    state = None
    if checkpoint is not None:
        meta = _checkpoint_meta(canonical, seed, basis, space.dim)
        state = CheckpointFile(Path(checkpoint), meta, resume=resume, t0=t0)
    opt = state.restore() if state is not None else None
    if opt is None:
        opt = new_optimizer(spec, space, seed)
    margin = opt.cut_margin if cut and robust.cut_allowed(spec) else None
    evaluator = BatchEvaluator(executor, fn, margin)
    stop_rule = run_generations(opt, space, evaluator, state, after_generation=progress)
    final = final_evaluation(opt, space, evaluator)
    wall_before = 0.0 if state is None else state.wall_before
    return result_of(canonical, opt, space, final, stop_rule=stop_rule, seed=seed,
                     wall_seconds=wall_before + time.perf_counter() - t0)


def result_of(
    spec: TaskSpec | CanonicalSpec,
    opt: CmaOptimizer,
    space: SearchSpace,
    final: FinalEvaluation,
    *,
    stop_rule: str,
    seed: int,
    wall_seconds: float,
) -> OptimizationResult:
    """The result document of a finished search (the command line's `--out` file, and a
    service job's result): the best candidate with its final evaluation and the flat spline's."""
    return OptimizationResult.build(
        spec,
        final.best_params,
        objective=final.best.objective,
        fell=final.best.fell,
        baseline_objective=final.flat.objective,
        baseline_fell=final.flat.fell,
        evaluations=opt.evaluations,
        iterations=opt.iterations,
        stop_rule=stop_rule,
        wall_seconds=wall_seconds,
        seed=seed,
        history=[asdict(h) for h in opt.history],
        basis_id=space.basis_id,
        reduced_params=None if space.basis is None else final.best_x,
        fall_direction=final.best.fall_direction,
        task_success=final.best.task_success,
        baseline_fall_direction=final.flat.fall_direction,
        baseline_task_success=final.flat.task_success,
        robust=robust.robust_document(space.spec, final.best_variants, final.flat_variants),
    )


__all__ = [
    "CANCELLED",
    "CHECKPOINT_FORMAT",
    "BatchEvaluator",
    "CheckpointFile",
    "initial_point",
    "load_checkpoint",
    "optimize",
    "result_of",
    "save_checkpoint",
]
