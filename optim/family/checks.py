"""The checks of a finished family (paper Table 2), a pure function of its runs' results.

**Fair comparisons** (`family_checks`, one Table 2 row per leave-out value):
  * the same stopping rules (the spec's `optimize` block) for the reduced run and the
    full-space run it is timed against, the same seed for both;
  * the relative error is against the REFERENCE objective: the better of the family member
    (the best chain run) and the cold full-space run at that value, so the reduced run is
    compared with the best full-space optimum known there, never a weak one;
  * speed-ups compare the reduced run with the cold full-space run (the only full-space run
    whose cost is a search from scratch): evaluations until the best is within
    CONVERGED_WITHIN (1 %) of the run's own final best ("to convergence"), until the
    slow-convergence rule's window began ("rule convergence": the paper's convergence
    iterations, which are below its window), and until each run first reached the cold full
    run's final objective ("to the full-space objective"; None when the reduced run never
    did).
**Strategy switches**: the library's own check (`parameter_distance`, `SWITCH_DISTANCE`), applied
to neighbouring members: a member whose spline parameters lie more than `switch_threshold`
(default SWITCH_DISTANCE = 0.15, RMS in box units) from the previous member's is flagged, the
switch lying between the two; the library never averages across it. Beside it, the largest
knot-time change from the previous member (s) and the member's leave-one-out reconstruction
error (the RMS of its row minus its projection on the k-component basis of the other members:
how well the family's low-dimensional surface holds it; on a small family every member's is
large, so it is reported, not used as a flag). Flags are per member, never averaged into rows.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from optim.errors import BasisError
from optim.family.plan import (
    PlannedRun,
    family_members,
    leave_one_out_basis,
    plan_runs,
    probe_points,
    reduced_run_id,
    reference_run_id,
    run_start,
)
from optim.family.spec import FamilySpec
from optim.outcome import EvalOutcome
from optim.pca import build_basis
from optim.result import OptimizationResult

#: "Converged" = the run's best within this fraction of its own final best.
CONVERGED_WITHIN = 0.01


def converged_at(history: Sequence[Mapping[str, Any]], within: float = CONVERGED_WITHIN) -> int:
    """Evaluations until the run's best so far was within `within` of its final best."""
    if not history:
        return 0
    final = float(history[-1]["best_so_far"])
    for h in history:
        if float(h["best_so_far"]) <= final + within * abs(final):
            return int(h["evaluations"])
    return int(history[-1]["evaluations"])


def rule_converged_at(result: OptimizationResult, window: int) -> int:
    """Evaluations at the slow-convergence rule's window start (the best was last improved by
    the rule's margin there); a run stopped by another rule: its whole count."""
    h = result.history
    if result.stop_rule != "slow_convergence" or len(h) <= window:
        return int(result.evaluations)
    return int(h[-1 - window]["evaluations"])


def evaluations_to_reach(history: Sequence[Mapping[str, Any]], target: float) -> int | None:
    """Evaluations until the best so far was <= target (None: never)."""
    for h in history:
        if float(h["best_so_far"]) <= target:
            return int(h["evaluations"])
    return None


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or b <= 0:
        return None
    return float(a) / float(b)


@dataclass(frozen=True)
class MemberRow:
    value: float
    run: str
    objective: float
    fell: bool
    task_success: bool | None
    baseline_objective: float
    evaluations: int
    stop_rule: str
    reconstruction_error: float | None  # leave-one-out, RMS box units
    switch: bool  # a strategy switch lies between the previous member and this one
    knot_shift: float | None  # s, largest knot-time change from the previous member
    distance: float | None  # RMS box units, spline parameters from the previous member


@dataclass(frozen=True)
class ProbeRow:
    value: float
    lower: float
    upper: float
    objective: float
    fell: bool
    task_success: bool | None
    member_objective: float
    excess: float  # objective / member's - 1


@dataclass(frozen=True)
class Table2Row:
    value: float
    k: int
    basis_members: int
    variance_explained: list[float]  # per component of the leave-one-out basis
    member_objective: float
    interpolated: ProbeRow | None
    reference_objective: float
    reference_source: str  # "member" | "cold"
    cold_objective: float
    cold_evaluations: int
    cold_converged_at: int
    cold_rule_converged_at: int
    reduced_start: str
    reduced_objective: float
    reduced_fell: bool
    reduced_task_success: bool | None
    reduced_evaluations: int
    reduced_converged_at: int
    reduced_rule_converged_at: int
    relative_error: float
    speedup_converged: float | None
    speedup_rule_converged: float | None
    cold_to_full: int | None
    reduced_to_full: int | None
    speedup_to_full: float | None


@dataclass(frozen=True)
class FamilyChecks:
    """The checks of a finished family (see module docstring)."""

    k: int
    variance_explained: list[float]  # the whole family's basis, every component
    basis: dict[str, Any] | None
    members: list[MemberRow]
    probes: list[ProbeRow]
    rows: list[Table2Row]
    switch_threshold: float
    medians: dict[str, float | None] = field(default_factory=dict)

    @property
    def switches(self) -> list[float]:
        return [m.value for m in self.members if m.switch]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["switches"] = self.switches
        return d


def parameter_distance(x: Sequence[float], y: Sequence[float]) -> float:
    """RMS distance of two CMRTs' spline parameters (box units); inf for two layouts."""
    a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return float(np.sqrt(np.mean((a - b) ** 2))) if a.shape == b.shape else float("inf")


def reconstruction_errors(
    k: int, members: Mapping[float, OptimizationResult]
) -> dict[float, float | None]:
    """Each member's leave-one-out reconstruction error (RMS over its spline parameters, box
    units) in the k-component basis of the other members; None when too few others."""
    out: dict[float, float | None] = {}
    vals = sorted(members)
    for v in vals:
        others = [members[u] for u in vals if u != v]
        if len(others) < k + 1:
            out[v] = None
            continue
        try:
            b = build_basis(others, k=k)
        except BasisError:
            out[v] = None
            continue
        r = members[v]
        row = np.append(np.asarray(r.params, dtype=float), float(r.spec["clip"]["duration"]))
        rec = b.reconstruct(b.scores(row))[0]
        d = (row - rec)[:-1]
        out[v] = float(np.sqrt(np.mean(d * d)))
    return out


def _member_rows(
    fs: FamilySpec, chosen: Mapping[float, tuple[str, OptimizationResult]]
) -> list[MemberRow]:
    """One row per member: its outcome, reconstruction error, distance and knot shift from the
    previous member, and whether a strategy switch lies between the two."""
    members = {v: res for v, (_, res) in chosen.items()}
    recon = reconstruction_errors(fs.k, members)
    rows: list[MemberRow] = []
    prev: OptimizationResult | None = None
    for v in sorted(members):
        rid, r = chosen[v]
        shift = None if prev is None else float(np.max(np.abs(
            np.asarray(r.knot_times) - np.asarray(prev.knot_times))))
        dist = None if prev is None else parameter_distance(r.params, prev.params)
        rows.append(MemberRow(v, rid, r.objective, r.fell, r.task_success,
                              r.baseline_objective, r.evaluations, r.stop_rule, recon.get(v),
                              dist is not None and dist > fs.switch_threshold, shift, dist))
        prev = r
    return rows


def _probe_rows(
    fs: FamilySpec, members: Mapping[float, OptimizationResult],
    probes: Mapping[float, EvalOutcome],
) -> dict[float, ProbeRow]:
    """value -> the interpolated CMRT's outcome there against the member's."""
    rows: dict[float, ProbeRow] = {}
    for v, _params, lo, hi in probe_points(fs, members):
        out = probes.get(v)
        if out is None:
            continue
        m = members[v].objective
        rows[v] = ProbeRow(v, lo, hi, out.objective, out.fell, out.task_success, m,
                           out.objective / m - 1.0)
    return rows


def _whole_basis(
    fs: FamilySpec, members: Mapping[float, OptimizationResult]
) -> tuple[dict[str, Any] | None, list[float]]:
    """The basis of every member (None when it cannot be made) and its variance explained."""
    if len(members) >= fs.k + 1:
        try:
            b = build_basis([members[v] for v in sorted(members)], k=fs.k, family=fs.family)
            return b.to_dict(), [float(x) for x in b.variance_explained]
        except BasisError:  # every member the same CMRT: nothing to reduce (basis None)
            pass
    return None, []


def _table2_row(
    fs: FamilySpec, v: float, red: OptimizationResult, cold: OptimizationResult,
    members: Mapping[float, OptimizationResult], start: str, probe: ProbeRow | None,
) -> Table2Row:
    """The row at leave-out value `v`: the reduced run against the reference and the cold run."""
    window = fs.base.optimize.window
    b = leave_one_out_basis(fs, members, v)
    member = members[v]
    ref_src = "cold" if cold.objective < member.objective else "member"
    ref = min(cold.objective, member.objective)
    c_conv, r_conv = converged_at(cold.history), converged_at(red.history)
    c_rule, r_rule = rule_converged_at(cold, window), rule_converged_at(red, window)
    c_full = evaluations_to_reach(cold.history, cold.objective)
    r_full = evaluations_to_reach(red.history, cold.objective)
    return Table2Row(
        value=v, k=fs.k, basis_members=len(members) - 1,
        variance_explained=[float(x) for x in b.variance_explained[: fs.k]],
        member_objective=member.objective, interpolated=probe,
        reference_objective=ref, reference_source=ref_src,
        cold_objective=cold.objective, cold_evaluations=cold.evaluations,
        cold_converged_at=c_conv, cold_rule_converged_at=c_rule,
        reduced_start=start,
        reduced_objective=red.objective, reduced_fell=red.fell,
        reduced_task_success=red.task_success, reduced_evaluations=red.evaluations,
        reduced_converged_at=r_conv, reduced_rule_converged_at=r_rule,
        relative_error=red.objective / ref - 1.0,
        speedup_converged=_ratio(c_conv, r_conv),
        speedup_rule_converged=_ratio(c_rule, r_rule),
        cold_to_full=c_full, reduced_to_full=r_full,
        speedup_to_full=_ratio(c_full, r_full),
    )


def _medians(rows: Sequence[Table2Row]) -> dict[str, float | None]:
    """The median speed-ups over the rows and the worst relative error."""

    def median(key: str) -> float | None:
        xs = [getattr(r, key) for r in rows if getattr(r, key) is not None]
        return float(np.median(xs)) if xs else None

    medians = {key: median(key) for key in ("speedup_converged", "speedup_rule_converged",
                                             "speedup_to_full")}
    medians["worst_relative_error"] = max((r.relative_error for r in rows), default=None)
    return medians


def family_checks(
    fs: FamilySpec,
    results: Mapping[str, OptimizationResult],
    probes: Mapping[float, EvalOutcome] | None = None,
    runs: Sequence[PlannedRun] | None = None,
) -> FamilyChecks:
    """The checks as a pure function of the finished runs' results (run id -> result) and the
    probes' outcomes (value -> outcome of the interpolated CMRT there)."""
    runs = list(runs) if runs is not None else plan_runs(fs)
    chosen = family_members(runs, results)
    members = {v: res for v, (_, res) in chosen.items()}
    probe_rows = _probe_rows(fs, members, probes or {})
    basis, variance = _whole_basis(fs, members)
    rows: list[Table2Row] = []
    for v in fs.leave_out:
        v = float(v)
        red = results.get(reduced_run_id(v))
        cold = results.get(reference_run_id(fs, runs, v))
        if red is None or cold is None or v not in members:
            continue
        run = next(r for r in runs if r.id == reduced_run_id(v))
        start = run_start(fs, run, runs, results).start
        rows.append(_table2_row(fs, v, red, cold, members, start, probe_rows.get(v)))
    return FamilyChecks(fs.k, variance, basis, _member_rows(fs, chosen),
                        sorted(probe_rows.values(), key=lambda p: p.value), rows,
                        fs.switch_threshold, _medians(rows))


__all__ = [
    "CONVERGED_WITHIN",
    "FamilyChecks",
    "MemberRow",
    "ProbeRow",
    "Table2Row",
    "converged_at",
    "evaluations_to_reach",
    "family_checks",
    "parameter_distance",
    "reconstruction_errors",
    "rule_converged_at",
]
