"""The plan of a family: a DAG of runs, each an ordinary optimisation (or, for `probes`, one
batch of evaluations) with the ids of the runs it needs (`plan_runs`, `ready_runs`), and where
each run starts (`run_start`):
  * members. `independent`: one run per value from the flat spline (the spec's `optimize`
    rules, "the main rules"). `continuation` (the paper's "previous optimization results as
    starting points"): chains that start from the flat spline (main rules) and warm-start each
    next value from the previous one's optimum with `warm.sigma0` and the `warm` rules (their
    cap at most the main rules' cap).
    `from`: low (one chain, increasing), high (decreasing), both (an increasing and a
    decreasing chain over every value; a value's member is the better of its two runs),
    middle (the middle value, then two chains outward from it). A member is ready as soon as
    its warm start exists.
  * references: at every leave-out value, a full-space run from the flat spline under the
    main rules, the same rules as the reduced run; a member run that already is one (an
    independent member, a chain's first value) is reused instead.
  * reduced: at every leave-out value, a run in a k-component basis of the OTHER values'
    members (main rules), started from the CMRT interpolated between the neighbouring members
    (`reduced_start: neighbours`; the nearest member's optimum at an end of the range) or
    from the box centre (`centre`). Needs every member.
  * probes: the CMRT interpolated at every interior value from the other members, evaluated
    once. Needs every member.
`ready_runs` orders ready runs by priority (the longest chain remainder first, then the
references, then what needs every member), so that a runner with a cap on active runs starts
the critical path first and keeps the workers busy with references meanwhile.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from optim.errors import InterpolationError
from optim.family.spec import WARM, FamilySpec, member_spec, value_id
from optim.interpolate import interpolate
from optim.pca import Basis, build_basis
from optim.result import OptimizationResult
from sim.spec import TaskSpec

#: Run kinds of the plan.
MEMBER = "member"
REFERENCE = "reference"
REDUCED = "reduced"
PROBES = "probes"


@dataclass(frozen=True)
class PlannedRun:
    """One run of the plan. `warm_from`: the run whose optimum starts this member (None: the
    flat spline); `needs`: runs that must be finished first; higher `priority` starts first."""

    id: str
    kind: str
    value: float | None
    warm_from: str | None = None
    needs: tuple[str, ...] = ()
    priority: int = 0

    @property
    def cold(self) -> bool:
        """A full-space run from the flat spline under the main rules."""
        return self.kind in (MEMBER, REFERENCE) and self.warm_from is None


def chains(fs: FamilySpec) -> list[tuple[str, list[float], float | None]]:
    """(direction, values in run order, the value whose member starts the chain or None)."""
    vs = fs.sorted_values
    if fs.strategy == "independent":
        return [("cold", [v], None) for v in vs]
    if fs.start_from == "low":
        return [("up", vs, None)]
    if fs.start_from == "high":
        return [("down", vs[::-1], None)]
    if fs.start_from == "both":
        return [("up", vs, None), ("down", vs[::-1], None)]
    mid = vs[(len(vs) - 1) // 2]
    out: list[tuple[str, list[float], float | None]] = [("mid", [mid], None)]
    if any(v > mid for v in vs):
        out.append(("up", [v for v in vs if v > mid], mid))
    if any(v < mid for v in vs):
        out.append(("down", [v for v in vs if v < mid][::-1], mid))
    return out


def member_run_id(direction: str, value: float) -> str:
    """The id of the member run at `value` of the chain going `direction`."""
    return f"member-{direction}-{value_id(value)}"


def reduced_run_id(value: float) -> str:
    """The id of the reduced run at a leave-out value."""
    return f"reduced-{value_id(value)}"


def plan_runs(fs: FamilySpec) -> list[PlannedRun]:
    """Every run of the family, in a deterministic order (see module docstring)."""
    runs: list[PlannedRun] = []
    heads: dict[float, str] = {}
    for direction, values, start in chains(fs):
        prev = None if start is None else member_run_id("mid", start)
        for i, v in enumerate(values):
            rid = member_run_id(direction, v)
            # The rest of the chain (this run included) waits on this run: longest first.
            runs.append(PlannedRun(rid, MEMBER, v, prev, () if prev is None else (prev,),
                                   priority=100 + len(values) - i))
            if prev is None:
                heads.setdefault(v, rid)
            prev = rid
    member_ids = tuple(r.id for r in runs)
    for v in fs.leave_out:
        if float(v) not in heads:
            runs.append(PlannedRun(f"reference-{value_id(v)}", REFERENCE, float(v),
                                   priority=50))
    for v in fs.leave_out:
        runs.append(PlannedRun(reduced_run_id(v), REDUCED, float(v), needs=member_ids,
                               priority=10))
    runs.append(PlannedRun(PROBES, PROBES, None, needs=member_ids, priority=0))
    return runs


def ready_runs(
    runs: Sequence[PlannedRun], done: Collection[str], running: Collection[str] = ()
) -> list[PlannedRun]:
    """Runs not done nor running whose needs are all done, highest priority first (ties: plan
    order)."""
    ready = [r for r in runs
             if r.id not in done and r.id not in running and all(n in done for n in r.needs)]
    order = {r.id: i for i, r in enumerate(runs)}
    return sorted(ready, key=lambda r: (-r.priority, order[r.id]))


def reference_run_id(fs: FamilySpec, runs: Sequence[PlannedRun], value: float) -> str:
    """The cold full-space run at `value`: a cold member there, else its reference run."""
    for r in runs:
        if r.kind == MEMBER and r.cold and r.value == value:
            return r.id
    return f"reference-{value_id(value)}"


def family_members(
    runs: Sequence[PlannedRun], results: Mapping[str, OptimizationResult]
) -> dict[float, tuple[str, OptimizationResult]]:
    """value -> (run id, result) of the family member: the best finished member run there
    (lowest objective; ties: plan order)."""
    out: dict[float, tuple[str, OptimizationResult]] = {}
    for r in runs:
        if r.kind != MEMBER or r.id not in results:
            continue
        res = results[r.id]
        assert r.value is not None
        if r.value not in out or res.objective < out[r.value][1].objective:
            out[r.value] = (r.id, res)
    return out


def member_results(
    runs: Sequence[PlannedRun], results: Mapping[str, OptimizationResult]
) -> dict[float, OptimizationResult]:
    """value -> result of the family member there (`family_members` without the run ids)."""
    return {v: res for v, (_, res) in family_members(runs, results).items()}


def leave_one_out_basis(
    fs: FamilySpec, members: Mapping[float, OptimizationResult], value: float
) -> Basis:
    """The k-component basis of every member but the one at `value`."""
    others = [members[v] for v in sorted(members) if v != value]
    return build_basis(others, k=fs.k, family=fs.family)


def interpolated_params(
    fs: FamilySpec, members: Mapping[float, OptimizationResult], value: float
) -> tuple[np.ndarray, float, float] | None:
    """Params at `value` interpolated from the OTHER members (their decoded splines, linearly
    between the neighbours on either side) and the two values used; None outside their range."""
    vals = [v for v in sorted(members) if v != value]
    if len(vals) < 2 or not vals[0] < value < vals[-1]:
        return None
    try:
        it = interpolate([members[v] for v in vals], value, key=fs.leaf, values=vals)
    except InterpolationError:
        return None
    return it.params(member_spec(fs, value)), it.lower_value, it.upper_value


@dataclass(frozen=True)
class RunStart:
    """Where a run starts: its spec, full-space x0 (None: flat spline / box centre), basis."""

    spec: TaskSpec
    x0: np.ndarray | None = None
    basis: Basis | None = None
    start: str = "flat"  # what x0 is, for reports


def run_start(
    fs: FamilySpec, run: PlannedRun, runs: Sequence[PlannedRun],
    results: Mapping[str, OptimizationResult],
) -> RunStart:
    """The spec, start point and basis of an optimisation run (member, reference, reduced)."""
    assert run.value is not None
    if run.kind == MEMBER and run.warm_from is not None:
        prev = results[run.warm_from]
        return RunStart(member_spec(fs, run.value, WARM), np.asarray(prev.params, dtype=float),
                        start=run.warm_from)
    if run.kind in (MEMBER, REFERENCE):
        return RunStart(member_spec(fs, run.value))
    if run.kind != REDUCED:
        raise ValueError(f"run {run.id!r} is not an optimisation")
    members = member_results(runs, results)
    basis = leave_one_out_basis(fs, members, run.value)
    spec = member_spec(fs, run.value)
    if fs.reduced_start == "centre":
        return RunStart(spec, None, basis, "box centre")
    got = interpolated_params(fs, members, run.value)
    if got is not None:
        x0, lo, hi = got
        return RunStart(spec, x0, basis, f"interpolated {value_id(lo)}-{value_id(hi)}")
    others = [v for v in members if v != run.value]
    near = min(others, key=lambda v: (abs(v - run.value), v))
    return RunStart(spec, np.asarray(members[near].params, dtype=float), basis,
                    f"member {value_id(near)}")


def probe_points(
    fs: FamilySpec, members: Mapping[float, OptimizationResult]
) -> list[tuple[float, np.ndarray, float, float]]:
    """(value, interpolated params, lower, upper) at every interior member value."""
    out = []
    for v in sorted(members):
        got = interpolated_params(fs, members, v)
        if got is not None:
            out.append((v, *got))
    return out


__all__ = [
    "MEMBER",
    "PROBES",
    "REDUCED",
    "REFERENCE",
    "PlannedRun",
    "RunStart",
    "chains",
    "family_members",
    "interpolated_params",
    "leave_one_out_basis",
    "member_results",
    "member_run_id",
    "plan_runs",
    "probe_points",
    "ready_runs",
    "reduced_run_id",
    "reference_run_id",
    "run_start",
]
