"""Rank-preserving early stop ("cut") of the candidate that already ranks last.

What pycma (4.x, the defaults `optim.cmaes.CmaOptimizer` uses) takes from one generation's
objective values, read from `CMAEvolutionStrategy.tell` and its stop dictionary:
  * the ranking of all lambda candidates: active CMA (`CMA_active`, on by default) gives every
    rank a weight, the worst lambda - mu ranks negative ones (popsize 10: weights
    0.456 ... 0.026, then -0.081 ... -0.555), so no rank carries zero weight and the order of
    any two candidates changes the covariance update;
  * values: the best (`fit.hist`, `histbest`: tolfunhist, tolstagnation), the median (ranks
    lambda//2 and lambda//2 + 1: `histmedian`, `median0`, `median_min`), rank int(0.75 lambda)+1
    (tolflatfitness compares it with the best), and the worst only through the current range
    max - min, in `tolfun` (range < tolfun and ...) and `tolfunrel` (range < tolfunrel x
    (median0 - median_min)).
`optim.cmaes.StopRules` (threshold, slow convergence, max evaluations) reads only the best
so far and the counts.

So a candidate may stop early, with a lower bound L of its objective reported instead of its
value, if and only if it is certainly the unique last of its generation: L > every other
candidate's (exact) value, and fl(L - best) >= tolfun (then range < tolfun is false with L as
with the true value, which is >= L; float subtraction is monotone) with tolfunrel = 0 (its
default: range < 0 never holds). Then the ranking, the best, the median and rank
int(0.75 lambda)+1 (lambda >= 2: never the last) are the same, hence pycma's mean, sigma,
covariance, random stream and every stop rule, and so the whole run. Two cut candidates would
have an unknown order between them, so at most one is cut, and only once every other
candidate of the generation is finished: `bound_for_last` is the bound given to the one left.
What changes: the generation's recorded `worst` is L (a lower bound) and the cut run's
simulated seconds are not spent.

The lower bound is `sim.rollout.Rollout.run(stop_above=...)`'s: min(sqrt(running sum of
squared CP error), F0), F0 = sqrt(steps) x support length (every fall scores at least F0;
task penalties are >= 0).

`verify(outcomes, margin)` re-checks the condition on the finished generation; `optim.loop`
re-evaluates a cut candidate without the cut should it ever fail (a safety net: the executors
only cut under it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from optim.outcome import EvalOutcome


def cut_margin(es: Any) -> float | None:
    """The margin fl(L - best) must reach for pycma strategy `es`, or None (no cut allowed):
    its `tolfun`, with `tolfunrel` 0 and active CMA's full ranking as above."""
    opts = es.opts
    try:
        tolfun = float(opts["tolfun"])
        tolfunrel = float(opts.get("tolfunrel", 0) or 0)
    except (TypeError, ValueError, KeyError):
        return None
    if tolfunrel != 0.0 or not math.isfinite(tolfun) or tolfun < 0.0:
        return None
    return tolfun


def bound_for_last(done: Sequence[float], margin: float) -> float:
    """The bound the last unfinished candidate of a generation must exceed to be cut, given
    the values of all the others: above their maximum and at least `margin` above their
    minimum (`verify` checks the exact float condition afterwards)."""
    if not done:
        return math.inf
    return max(max(done), min(done) + margin)


def verify(outcomes: Sequence[EvalOutcome], margin: float | None) -> bool:
    """True when the generation's cut (if any) keeps the run identical: at most one cut
    outcome, its value strictly above every other's and fl(value - best) >= margin."""
    cut = [i for i, o in enumerate(outcomes) if o.cut]
    if not cut:
        return True
    if margin is None or len(cut) > 1 or len(outcomes) < 2:
        return False
    i = cut[0]
    lb = outcomes[i].objective
    others = [o.objective for j, o in enumerate(outcomes) if j != i]
    return all(lb > f for f in others) and (lb - min(others)) >= margin


__all__ = ["bound_for_last", "cut_margin", "verify"]
