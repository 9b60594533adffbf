"""The family's one state machine: what a family does next, decided by `next_actions` from a
`FamilyState` alone. Two drivers carry its actions out and keep no decision of their own, the
way `optim.loop` serves both job protocols: `cmrt family run` (`optim.family_run`: threads of
this process over one pool, files) and the service (`worker.family`: jobs in the store).

The decisions, in this order:
  1. cancel requested -> `Cancel`: stop the runs under way; the family ends cancelled once none
     runs (the driver says when its runs have stopped);
  2. a run failed -> `Fail`, naming the first failed run and its reason, and the runs under way
     to stop;
  3. every run of the plan finished and the probes evaluated -> `Finish` (the driver then
     makes the family's document, `optim.family.report.family_report`: not a decision);
  4. otherwise every ready run (its needs finished, `ready_runs`: the critical path first), as
     many as the capacity leaves room for: `StartRun` with where it starts (`run_start`), or,
     for the probes, `EvaluateProbes` with the points to evaluate (the CMRT interpolated at
     each interior member value from the other members).
No action: runs are under way and nothing else is ready; the driver waits for one to end.
The actions depend on the state only, so a driver resumed from a partial state (finished runs
reloaded, runs under way found again) continues exactly where the family was.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from optim.family.plan import (
    PROBES,
    PlannedRun,
    RunStart,
    member_results,
    plan_runs,
    probe_points,
    ready_runs,
    run_start,
)
from optim.family.spec import FamilySpec
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult


@dataclass(frozen=True)
class FamilyState:
    """What a driver knows of a family at one moment.

    `results`: the finished runs (run id -> result); `running`: the runs started and not
    finished (not the probes); `probes`: the probes' outcomes once evaluated (None: not yet);
    `probing`: their evaluation is under way; `failed`: runs that ended without a result (run
    id -> reason, in the order found); `cancel_requested`: someone asked the family to stop;
    `capacity`: at most this many runs (the probes' evaluation included) under way at once
    (None: no cap)."""

    results: Mapping[str, OptimizationResult] = field(default_factory=dict)
    running: Collection[str] = frozenset()
    probes: Mapping[float, EvalOutcome] | None = None
    probing: bool = False
    failed: Mapping[str, str] = field(default_factory=dict)
    cancel_requested: bool = False
    capacity: int | None = None

    @property
    def done(self) -> set[str]:
        """The runs finished, the probes included once evaluated."""
        return set(self.results) | ({PROBES} if self.probes is not None else set())

    @property
    def active(self) -> set[str]:
        """The runs under way, the probes included while evaluated."""
        return set(self.running) | ({PROBES} if self.probing else set())


@dataclass(frozen=True)
class StartRun:
    """Start an optimisation run of the plan from `start` (spec, x0, basis)."""

    run: PlannedRun
    start: RunStart


@dataclass(frozen=True)
class EvaluateProbes:
    """Evaluate the CMRT at each (value, full-space params) once, with that value's member's
    objective; the outcomes are the family's probes."""

    points: tuple[tuple[float, np.ndarray], ...]


@dataclass(frozen=True)
class Fail:
    """The family fails: `run_id` ended without a result for `reason`; stop the runs `stop`."""

    run_id: str
    reason: str
    stop: tuple[str, ...]


@dataclass(frozen=True)
class Cancel:
    """The family is cancelled: stop the runs `stop`; it ends `cancelled` once none runs."""

    stop: tuple[str, ...]


@dataclass(frozen=True)
class Finish:
    """Every run finished and the probes evaluated: the family is done, its document made
    from the state's results and probes (`optim.family.report.family_report`)."""


Action = StartRun | EvaluateProbes | Fail | Cancel | Finish


def next_actions(
    fs: FamilySpec, state: FamilyState, runs: Sequence[PlannedRun] | None = None
) -> list[Action]:
    """The family's next actions from its state (see module docstring); `runs`: the plan
    (`plan_runs(fs)`, given when the driver has it already). Raises the plan's arithmetic
    errors (`optim.errors.OptimError`: a basis or an interpolation these members cannot
    give); the same state gives them again."""
    runs = list(runs) if runs is not None else plan_runs(fs)
    under_way = tuple(r.id for r in runs if r.id in state.running)
    if state.cancel_requested:
        return [Cancel(under_way)]
    if state.failed:
        run_id, reason = next(iter(state.failed.items()))
        return [Fail(run_id, reason, under_way)]
    done = state.done
    if all(r.id in done for r in runs):
        return [Finish()]
    active = state.active
    ready = ready_runs(runs, done, active)
    if state.capacity is not None:
        ready = ready[: max(0, state.capacity - len(active))]
    return [_evaluate_probes(fs, runs, state.results) if run.kind == PROBES
            else StartRun(run, run_start(fs, run, runs, state.results)) for run in ready]


def _evaluate_probes(
    fs: FamilySpec, runs: Sequence[PlannedRun], results: Mapping[str, OptimizationResult]
) -> EvaluateProbes:
    members = member_results(runs, results)
    return EvaluateProbes(tuple((v, params) for v, params, _lo, _hi in probe_points(fs, members)))


__all__ = [
    "Action",
    "Cancel",
    "EvaluateProbes",
    "Fail",
    "FamilyState",
    "Finish",
    "StartRun",
    "next_actions",
]
