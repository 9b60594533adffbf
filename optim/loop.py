"""One CMA-ES optimisation loop, shared by `cmrt optimize` (optim.run) and the service's job
driver (worker.driver). What differs between them sits behind two small interfaces:

  * `CandidateEvaluator.evaluate(generation, candidates)`: how one generation's full-space
    parameter vectors become outcomes (a local executor for the CLI; the store and a local pool
    or Celery for the service). Generation numbers are 0-based; `FINAL_GENERATION` (-1) is the
    final re-evaluation of the flat spline and the best candidate.
  * `RunState`: where the optimizer is restored from and saved to after every generation
    (a checkpoint file for the CLI; the store's generation records for the service).

Pieces, each written once:
  `SearchSpace.of(spec, basis, x0)`  the search dimension, start point and decoder to full
                                     params (full space: clip into [0, 1]; a PCA basis: decode at
                                     the spec's duration);
  `new_optimizer(spec, space, seed)`  a CmaOptimizer with the spec's sigma0, popsize and rules;
  `step(...)`                         ask, evaluate, the every-candidate-failed check, tell;
  `run_generations(...)`              steps until a stop rule fires, saving after each one and
                                     calling `after_generation(stats)`: True from it stops the
                                     loop with `CANCELLED`;
  `final_evaluation(...)`             the flat spline and the best candidate evaluated once more;
                                     `FinalEvaluation.winner` says which of the two is better
                                     (the flat spline counts among the candidates: a library
                                     entry is never worse than no anticipation).

Nothing here imports web, queue or database code.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from optim import rankcut, robust
from optim.cmaes import CmaOptimizer, GenerationStats, StopRules
from optim.errors import EvaluationError
from optim.outcome import EvalOutcome
from optim.spline import check_params, flat_params

if TYPE_CHECKING:
    from optim.pca import Basis
    from sim.spec import TaskSpec

#: Generation number of the final re-evaluation (index 0: flat spline, 1: best candidate).
FINAL_GENERATION = -1
#: Stop rule recorded when `after_generation` asks to stop.
CANCELLED = "cancelled"
#: `FinalEvaluation.winner`: the best searched candidate, or the flat spline (no CMRT).
WINNER_SEARCH = "search"
WINNER_FLAT = "flat"


class CandidateEvaluator(Protocol):
    """Evaluates one generation of candidates.

    Contract: returns one `EvalOutcome` per candidate, in order. A candidate whose objective
    raised has `error` set (it ranks worst); a failure of the whole batch (a worker process
    died past its attempts, a timeout, the job cancelled) is an exception, never a short list.
    Idempotent per (generation, candidates): asked again after a restart with the same
    candidates it may return stored outcomes instead of evaluating again.
    """

    def evaluate(self, generation: int, candidates: Sequence[np.ndarray]) -> list[EvalOutcome]:
        ...


class RunState(Protocol):
    """Where the optimizer lives between generations.

    Contract: `restore()` returns the optimizer saved last (None: start afresh) and raises the
    store's or checkpoint's own error when it cannot; `save(...)` is called after each told
    generation, before `after_generation`, and must be atomic: after a crash `restore()`
    returns either the state before or after that generation, never a mix.
    """

    def restore(self) -> CmaOptimizer | None:
        ...

    def save(
        self,
        opt: CmaOptimizer,
        generation: int,
        stats: GenerationStats,
        candidates: Sequence[np.ndarray],
        wall_seconds: float,
    ) -> None:
        ...


@dataclass(frozen=True)
class SearchSpace:
    """The space CMA-ES searches: `dim` coordinates in [0, 1], starting at `start`;
    `to_full(x)` maps a point to the spec's full CMRT parameter vector."""

    spec: TaskSpec
    dim: int
    start: np.ndarray
    basis: Basis | None = None

    @classmethod
    def of(
        cls,
        spec: TaskSpec,
        basis: Basis | None = None,
        x0: Sequence[float] | np.ndarray | None = None,
    ) -> SearchSpace:
        """Full space: x0 (checked, clipped into [0, 1]) or the flat spline. Reduced space: x0
        projected into the basis box (`Basis.encode` at the spec's duration), or the box centre
        (u = 0.5, about the family mean). Raises BasisError if the basis does not fit."""
        if basis is None:
            start = flat_params(spec) if x0 is None else check_params(spec, x0)
            return cls(spec, spec.cmrt_dimension, start)
        basis.check_spec(spec)
        if x0 is None:
            start = np.full(basis.k, 0.5)
        else:
            start = basis.encode(check_params(spec, x0), spec.clip.duration)
        return cls(spec, basis.k, start, basis)

    def to_full(self, x: np.ndarray) -> np.ndarray:
        if self.basis is None:
            return np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
        return self.basis.decode(x, self.spec.clip.duration)

    @property
    def basis_id(self) -> str | None:
        return None if self.basis is None else self.basis.id


def new_optimizer(spec: TaskSpec, space: SearchSpace, seed: int) -> CmaOptimizer:
    """A fresh CmaOptimizer for the spec's `optimize` block, started at `space.start`."""
    return CmaOptimizer(
        space.dim,
        seed=int(seed),
        x0=space.start,
        sigma0=spec.optimize.sigma0,
        popsize=spec.optimize.popsize,
        rules=StopRules.from_config(spec.optimize),
    )


@dataclass(frozen=True)
class StepResult:
    generation: int
    stats: GenerationStats
    candidates: list[np.ndarray]  # full-space params, in index order
    outcomes: list[EvalOutcome]


def step(opt: CmaOptimizer, space: SearchSpace, evaluator: CandidateEvaluator) -> StepResult:
    """One generation: ask, evaluate through `evaluator`, tell. A robust spec's candidates are
    evaluated at their K variants, each its own evaluation point, and aggregated
    (`optim.robust`). Raises EvaluationError when the evaluator returns the wrong number of
    outcomes or every candidate failed."""
    generation = opt.iterations
    xs = opt.ask()
    full = [space.to_full(x) for x in xs]
    pts = robust.points(space.spec, full)
    outs = evaluator.evaluate(generation, pts)
    if len(outs) != len(pts):
        raise EvaluationError(
            f"generation {generation}: {len(outs)} outcomes for {len(pts)} evaluation points"
        )
    margin = opt.cut_margin if robust.cut_allowed(space.spec) else None
    if not rankcut.verify(outs, margin):
        # Never expected (the executors cut only under the condition): evaluate the cut
        # points in full, one at a time (a single point is never cut).
        outs = list(outs)
        for i, o in enumerate(outs):
            if o.cut:
                outs[i] = evaluator.evaluate(generation, [pts[i]])[0]
    outs = robust.aggregate(space.spec, outs)
    if all(o.error is not None for o in outs):
        raise EvaluationError(
            f"every candidate of generation {generation} failed to evaluate; first error: "
            f"{outs[0].error}"
        )
    stats = opt.tell(xs, [o.objective for o in outs])
    return StepResult(generation, stats, full, list(outs))


AfterGeneration = Callable[[GenerationStats], "bool | None"]


def run_generations(
    opt: CmaOptimizer,
    space: SearchSpace,
    evaluator: CandidateEvaluator,
    state: RunState | None = None,
    *,
    after_generation: AfterGeneration | None = None,
    clock: Callable[[], float] | None = None,
) -> str:
    """Step until a stop rule of `opt` fires; returns its name (or CANCELLED).

    After each generation: `state.save(...)` (with the generation's wall seconds by `clock`),
    then `after_generation(stats)`; True from it stops with CANCELLED.
    """
    import time

    now = clock or time.monotonic
    stop_rule = opt.stop()
    while stop_rule is None:
        t0 = now()
        res = step(opt, space, evaluator)
        if state is not None:
            state.save(opt, res.generation, res.stats, res.candidates, now() - t0)
        if after_generation is not None and after_generation(res.stats) is True:
            return CANCELLED
        stop_rule = opt.stop()
    return stop_rule


@dataclass(frozen=True)
class FinalEvaluation:
    """The flat spline and the best searched candidate, evaluated once more."""

    flat_params: np.ndarray
    flat: EvalOutcome
    best_params: np.ndarray
    best: EvalOutcome
    #: Search-space point of `best_params` (the reduced coordinates with a basis).
    best_x: np.ndarray
    #: A robust spec's variants' own outcomes (`sim.robust.variant_values` order), else empty.
    flat_variants: tuple[EvalOutcome, ...] = ()
    best_variants: tuple[EvalOutcome, ...] = ()

    @property
    def winner(self) -> str:
        """WINNER_FLAT when the flat spline is strictly better than the best candidate
        (lower objective), else WINNER_SEARCH."""
        return WINNER_FLAT if self.flat.objective < self.best.objective else WINNER_SEARCH

    @property
    def chosen(self) -> tuple[np.ndarray, EvalOutcome]:
        """Params and outcome of the winner."""
        if self.winner == WINNER_FLAT:
            return self.flat_params, self.flat
        return self.best_params, self.best


def final_evaluation(
    opt: CmaOptimizer, space: SearchSpace, evaluator: CandidateEvaluator
) -> FinalEvaluation:
    """Evaluate the flat spline (index 0) and the best candidate (index 1) as generation
    FINAL_GENERATION (a robust spec: each at its K variants, indices 0..K-1 and K..2K-1).
    Raises EvaluationError if either fails."""
    best_x = opt.best_x
    if best_x is None:
        raise EvaluationError("no generation was told: there is no best candidate")
    flat = flat_params(space.spec)
    best = space.to_full(best_x)
    pts = robust.points(space.spec, [flat, best])
    outs = evaluator.evaluate(FINAL_GENERATION, pts)
    if len(outs) != len(pts):
        raise EvaluationError(f"final evaluation: {len(outs)} outcomes for {len(pts)} points")
    k = robust.samples(space.spec)
    both = robust.aggregate(space.spec, outs)
    for label, out in zip(("baseline (flat spline)", "best CMRT"), both, strict=True):
        if out.error is not None:
            raise EvaluationError(f"final evaluation of the {label} failed: {out.error}")
    variants = (tuple(outs[:k]), tuple(outs[k:])) if k > 1 else ((), ())
    return FinalEvaluation(flat, both[0], best, both[1], best_x, *variants)


__all__ = [
    "CANCELLED",
    "FINAL_GENERATION",
    "WINNER_FLAT",
    "WINNER_SEARCH",
    "CandidateEvaluator",
    "FinalEvaluation",
    "RunState",
    "SearchSpace",
    "StepResult",
    "final_evaluation",
    "new_optimizer",
    "run_generations",
    "step",
]
