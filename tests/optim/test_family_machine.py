"""The family state machine (optim.family.machine) driven directly: ready runs start from
their starts (critical path first, within the capacity), a failed run fails the family,
cancel stops what runs, the probes come after the members, the report at the end, and a
family resumed from a partial state takes the same steps to the same report."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from optim.family.machine import (
    Cancel,
    EvaluateProbes,
    Fail,
    FamilyState,
    Finish,
    StartRun,
    next_actions,
)
from optim.family.plan import MEMBER, PROBES, REDUCED, plan_runs
from optim.family.report import family_report
from optim.family.spec import FamilySpec, member_spec, parse_family
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult

BASE: dict[str, Any] = {
    "name": "fam", "family": "fam", "task": {"type": "quiet_stance"},
    "clip": {"preparation": 1.0, "duration": 0.4, "decay": 1.0},
    "optimize": {"min_evaluations": 0, "window": 2, "improvement": 0.01,
                 "max_evaluations": 40},
}
VALUES = [1.0, 1.5, 2.0, 2.5, 3.0]


def family(**kw: Any) -> FamilySpec:
    return parse_family({"spec": BASE, "param": "clip.decay", "values": VALUES,
                         "strategy": "continuation", "from": "both", "leave_out": [2.0],
                         "k": 2, "seed": 1, **kw})


def finished(fs: FamilySpec, action: StartRun) -> OptimizationResult:
    """A made-up result of a started run, a function of the run and its start alone: the
    members lie on a curve along the value (a warm start nudges them), a reduced run is a
    little worse than its start."""
    run, st = action.run, action.start
    assert run.value is not None
    d = member_spec(fs, run.value).cmrt_dimension
    t = np.linspace(0.0, 1.0, d)
    params = 0.5 + 0.2 * np.sin(3.0 * t + run.value) + 0.05 * run.value * t
    if st.x0 is not None:
        params = 0.5 * (params + np.asarray(st.x0))
    objective = 1.0 + run.value + (0.01 if run.warm_from else 0.0) + (
        0.02 if run.kind == REDUCED else 0.0)
    bests = [objective + 0.3, objective + 0.1, objective]
    history = [{"iteration": i + 1, "evaluations": 8 * (i + 1), "best": b, "median": b,
                "worst": b, "sigma": 0.1, "best_so_far": b} for i, b in enumerate(bests)]
    return OptimizationResult.build(st.spec, params, objective=objective,
                                     baseline_objective=9.0, evaluations=24, iterations=3,
                                     stop_rule="slow_convergence", history=history,
                                     task_success=True)


def probed(action: EvaluateProbes) -> dict[float, EvalOutcome]:
    return {v: EvalOutcome(objective=1.5 + v + float(np.mean(p))) for v, p in action.points}


def drive(fs: FamilySpec, state: FamilyState, *, steps: int | None = None
          ) -> tuple[FamilyState, list[str], dict[str, Any] | None]:
    """Run the machine's actions to their end, one step at a time (every run started in a
    step finishes before the next): the state after `steps` steps (all: None), the runs
    started in order and the report once finished."""
    started: list[str] = []
    n = 0
    while steps is None or n < steps:
        actions = next_actions(fs, state)
        results, probes = dict(state.results), state.probes
        for a in actions:
            if isinstance(a, Finish):
                return state, started, family_report(fs, state.results, state.probes)
            if isinstance(a, StartRun):
                started.append(a.run.id)
                results[a.run.id] = finished(fs, a)
            elif isinstance(a, EvaluateProbes):
                started.append(PROBES)
                probes = probed(a)
            else:
                raise AssertionError(a)
        assert actions, "the machine stopped with nothing under way"
        state = FamilyState(results, probes=probes)
        n += 1
    return state, started, None


def test_ready_runs_start_from_their_starts_critical_path_first() -> None:
    fs = family(leave_out=[2.0])
    actions = next_actions(fs, FamilyState())
    assert [type(a) for a in actions] == [StartRun] * 3
    assert [a.run.id for a in actions] == ["member-up-1", "member-down-3", "reference-2"]
    assert all(a.start.x0 is None and a.start.start == "flat" for a in actions)
    # the capacity counts what is under way, the probes included
    capped = next_actions(fs, FamilyState(running={"member-up-1"}, capacity=2))
    assert [a.run.id for a in capped] == ["member-down-3"]
    assert next_actions(fs, FamilyState(running={"member-up-1", "member-down-3"},
                                        capacity=2)) == []
    # a chain's next member starts warm from its predecessor's optimum, under the warm rules
    head = finished(fs, actions[0])
    nxt = next_actions(fs, FamilyState({"member-up-1": head},
                                       running={"member-down-3", "reference-2"}))
    assert [a.run.id for a in nxt] == ["member-up-1.5"]
    st = nxt[0].start
    assert st.start == "member-up-1" and st.spec == member_spec(fs, 1.5, "warm")
    np.testing.assert_array_equal(st.x0, np.asarray(head.params))


def test_a_failed_run_fails_the_family_naming_it_and_stops_the_others() -> None:
    fs = family()
    state = FamilyState(running={"member-down-3", "member-up-1"},
                        failed={"member-up-1.5": "job 7: boom", "reference-2": "later"})
    assert next_actions(fs, state) == [
        Fail("member-up-1.5", "job 7: boom", ("member-up-1", "member-down-3"))]


def test_cancel_stops_what_runs_before_anything_else() -> None:
    fs = family()
    running = FamilyState(running={"reference-2"}, failed={"member-up-1": "boom"},
                          cancel_requested=True)
    assert next_actions(fs, running) == [Cancel(("reference-2",))]
    assert next_actions(fs, FamilyState(cancel_requested=True)) == [Cancel(())]


def test_probes_and_reduced_runs_come_after_every_member_then_the_report() -> None:
    fs = family()
    runs = plan_runs(fs)
    members = [r for r in runs if r.kind == MEMBER]
    state, _started, _ = drive(fs, FamilyState(), steps=len(VALUES))  # the two chains
    assert set(state.results) == {r.id for r in members} | {"reference-2"}
    actions = next_actions(fs, state)
    assert [a.run.id for a in actions if isinstance(a, StartRun)] == ["reduced-2"]
    probes, = (a for a in actions if isinstance(a, EvaluateProbes))
    assert [v for v, _ in probes.points] == [1.5, 2.0, 2.5]  # the interior values
    # one member missing: neither the probes nor the reduced run are ready
    fewer = {k: v for k, v in state.results.items() if k != "member-down-1"}
    assert all(isinstance(a, StartRun) and a.run.id == "member-down-1"
               for a in next_actions(fs, FamilyState(fewer)))
    # the probes under way are not handed out again; the family waits for them
    reduced = finished(fs, next(a for a in actions if isinstance(a, StartRun)))
    done = {**state.results, "reduced-2": reduced}
    assert next_actions(fs, FamilyState(done, probing=True)) == []
    outcomes = probed(probes)
    end = next_actions(fs, FamilyState(done, probes=outcomes))
    assert end == [Finish()]
    assert family_report(fs, done, outcomes)["checks"]["rows"][0]["value"] == 2.0


@pytest.mark.parametrize("steps", [1, 2, 3, 4])
def test_a_family_resumed_from_a_partial_state_takes_the_same_steps(steps: int) -> None:
    fs = family(strategy="continuation", **{"from": "middle"}, leave_out=[1.0, 2.0])
    _, all_started, report = drive(fs, FamilyState())
    assert all_started == ["member-mid-2", "reference-1", "member-up-2.5", "member-down-1.5",
                           "member-up-3", "member-down-1", "reduced-1", "reduced-2", PROBES]
    assert report is not None and [r["value"] for r in report["checks"]["rows"]] == [1.0, 2.0]
    partial, first, _ = drive(fs, FamilyState(), steps=steps)
    # what a driver reloads after a kill: the finished runs and the probes, nothing running
    resumed = FamilyState(dict(partial.results), probes=partial.probes)
    _, rest, again = drive(fs, resumed)
    assert first + rest == all_started
    assert again == report
