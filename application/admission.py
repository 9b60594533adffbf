"""Admission of a job: its budget, and the server's ceiling on it.

A job's budget is what it may cost at most, in simulated seconds: every evaluation simulates
one clip, so

    evaluations  = max_evaluations + (popsize - 1) + 2
    sim_seconds  = evaluations x clip length (preparation + duration + decay)

(the cap is checked between generations, so the last generation may overshoot it by fewer than
`popsize` evaluations; the final re-evaluation of the flat spline and the best candidate adds
2). A robust spec (`optimize.robust`, K variants) simulates K clips per evaluation, each as long
as its variant's clip: evaluations count clips (x K) and the clip length is the longest
variant's. `popsize` is the spec's, or pycma's default 4 + floor(3 ln d) for the d searched
coordinates. A CPU second buys roughly 14 simulated seconds on the development machine
(`cmrt bench`), so the default ceiling of 50,000 simulated seconds is about an hour of one
core.

`check(spec, settings)` raises `BudgetExceeded` (a domain error: the HTTP layer answers 422 with
its message, the driver fails a job that was accepted under a higher ceiling) when the budget is
above `settings.max_job_sim_seconds` (CMRT_MAX_JOB_SIM_SECONDS).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from application.errors import InvalidRequest
from cmrt.settings import Settings
from optim.family.plan import MEMBER, PROBES, REDUCED, plan_runs
from optim.family.spec import MAIN, WARM, FamilySpec, member_spec
from optim.robust import samples
from sim.robust import variant_values
from sim.spec import TaskSpec

#: Evaluations added to the cap: the final flat-spline and best-candidate re-evaluation.
FINAL_EVALUATIONS = 2


class BudgetExceeded(InvalidRequest):  # noqa: N818 - the name says what happened
    """A job's budget is above the server's ceiling; the message names the field and rule."""


def default_popsize(dimension: int) -> int:
    """pycma's default population for a `dimension`-dimensional search."""
    return 4 + int(3 * math.log(max(dimension, 1)))


@dataclass(frozen=True)
class Budget:
    """The most a job may cost (see the module docstring)."""

    evaluations: int
    clip_seconds: float
    sim_seconds: float
    ceiling_sim_seconds: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def budget(spec: TaskSpec, settings: Settings | None = None, *, dimension: int | None = None
           ) -> Budget:
    """The job's budget; `dimension` is the searched one (a PCA basis' k; default the spec's)."""
    opt = spec.optimize
    popsize = opt.popsize or default_popsize(dimension or spec.cmrt_dimension)
    evaluations = (int(opt.max_evaluations) + popsize - 1 + FINAL_EVALUATIONS) * samples(spec)
    clip = _longest_clip(spec)
    return Budget(
        evaluations=evaluations,
        clip_seconds=clip,
        sim_seconds=evaluations * clip,
        ceiling_sim_seconds=None if settings is None else settings.max_job_sim_seconds,
    )


def _longest_clip(spec: TaskSpec) -> float:
    """The clip length (s), of the longest variant for a robust spec varying the clip."""
    rb = spec.optimize.robust
    if rb is None:
        return float(spec.clip.length)
    c = spec.clip
    return max(float(v.get("clip.preparation", c.preparation) + v.get("clip.duration", c.duration)
                     + v.get("clip.decay", c.decay)) for v in variant_values(rb))


def check(spec: TaskSpec, settings: Settings, *, dimension: int | None = None) -> Budget:
    """The job's budget, or BudgetExceeded when it is above the server's ceiling."""
    b = budget(spec, settings, dimension=dimension)
    ceiling = settings.max_job_sim_seconds
    if b.sim_seconds > ceiling:
        k = samples(spec)
        overshoot = b.evaluations // k - int(spec.optimize.max_evaluations)
        most = max(0, int(ceiling // b.clip_seconds) // k - overshoot)
        raise BudgetExceeded(
            f"optimize.max_evaluations: the job may simulate up to {b.sim_seconds:,.0f} s "
            f"({b.evaluations} evaluations x {b.clip_seconds:g} s clips"
            f"{f', {k} variants per candidate' if k > 1 else ''}), above this server's "
            f"ceiling of {ceiling:,.0f} simulated seconds per job (CMRT_MAX_JOB_SIM_SECONDS); "
            f"lower optimize.max_evaluations to at most {most} or shorten the clip"
        )
    return b


def family_budget(fs: FamilySpec, settings: Settings) -> Budget:
    """A family's budget: the sum over the runs of its plan (members under the main or the
    warm rules, references, reduced runs searching k coordinates) and one evaluation per
    probe; BudgetExceeded when it is above the same ceiling as a job's (the whole family is
    admitted or nothing is)."""
    evaluations, sim = 0, 0.0
    clip = 0.0
    for run in plan_runs(fs):
        if run.kind == PROBES:
            spec = member_spec(fs, fs.sorted_values[0])
            n = len(fs.values)
            evaluations += n
            sim += n * float(spec.clip.length)
            continue
        role = WARM if run.kind == MEMBER and run.warm_from is not None else MAIN
        spec = member_spec(fs, run.value, role)
        b = budget(spec, settings, dimension=fs.k if run.kind == REDUCED else None)
        evaluations += b.evaluations
        sim += b.sim_seconds
        clip = max(clip, b.clip_seconds)
    ceiling = settings.max_job_sim_seconds
    if sim > ceiling:
        raise BudgetExceeded(
            f"values: the family's runs may simulate up to {sim:,.0f} s in all ({evaluations} "
            f"evaluations), above this server's ceiling of {ceiling:,.0f} simulated seconds per "
            f"job or family (CMRT_MAX_JOB_SIM_SECONDS); use fewer values or leave-out values, "
            f"or lower optimize.max_evaluations / warm.max_evaluations")
    return Budget(evaluations=evaluations, clip_seconds=clip, sim_seconds=sim,
                  ceiling_sim_seconds=ceiling)


__all__ = ["FINAL_EVALUATIONS", "Budget", "BudgetExceeded", "budget", "check", "default_popsize",
           "family_budget"]
