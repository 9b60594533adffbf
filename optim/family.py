"""Families of CMRTs along one task parameter (paper sections 5.3 and 6.2, Table 2): the spec,
the plan of optimisations, and the checks. Pure: no process pool, no files, no web, queue or
database code; `optim.family_run` runs a family in this process, a service can run the same
plan as jobs.

**The spec** (`FamilySpec`, `parse_family`): a base task spec, the path of one number in it
(`param`, e.g. `task.mass`), its `values`, a `strategy` and the checks' settings. Each member
is the base spec with the number at `param` set to the value (named `<family>_<leaf><value>`,
family kept); every value must be accepted by the task's validator.

**The plan** (`plan_runs`, `ready_runs`): a DAG of runs, each an ordinary optimisation (or,
for `probes`, one batch of evaluations) with the ids of the runs it needs:
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
**Strategy switches**: each member's leave-one-out reconstruction error, the RMS over its
spline parameters (box units, [0, 1]) of its row minus its projection on the k-component basis
of the other members; above `switch_threshold` (default SWITCH_THRESHOLD = 0.05, 5 % of the
box) the member is flagged: its optimum is not on the family's low-dimensional surface (e.g.
knots that jump between neighbours), and interpolation across it is not to be trusted. The
largest knot-time change from the previous member (s) is reported beside it. Flags are
reported per member, never averaged into the rows.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, model_validator

from optim.errors import BasisError, InterpolationError, OptimError
from optim.interpolate import interpolate
from optim.outcome import EvalOutcome
from optim.pca import Basis, build_basis
from optim.result import OptimizationResult
from sim.errors import SpecError
from sim.spec import OptimizeConfig, TaskSpec, parse_spec
from sim.specbase import StrictModel

#: Run kinds of the plan.
MEMBER = "member"
REFERENCE = "reference"
REDUCED = "reduced"
PROBES = "probes"
#: "Converged" = the run's best within this fraction of its own final best.
CONVERGED_WITHIN = 0.01
#: Default leave-one-out reconstruction error (RMS, box units) above which a member is flagged.
SWITCH_THRESHOLD = 0.05
FAMILY_FORMAT = "cmrt-family/1"


class FamilyError(OptimError, ValueError):
    """A family spec is invalid (the message names the field and the rule)."""


class WarmConfig(StrictModel):
    """Continuation members after a chain's first: CMA-ES step and stopping rules."""

    sigma0: Annotated[float, Field(gt=0.0, le=1.0)] = 0.05
    min_evaluations: Annotated[int, Field(ge=0)] = 0
    window: Annotated[int, Field(ge=1)] = 5
    improvement: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.01
    max_evaluations: Annotated[int, Field(ge=1, le=100_000)] = 100


def _vid(v: float) -> str:
    """A value as it appears in run ids and names."""
    return format(float(v), ".12g").replace("+", "")


def get_path(data: Mapping[str, Any], path: str) -> Any:
    """The entry at a dotted path of a nested mapping; KeyError naming the missing part."""
    node: Any = data
    for i, part in enumerate(path.split(".")):
        if not isinstance(node, Mapping) or part not in node:
            raise KeyError(".".join(path.split(".")[: i + 1]))
        node = node[part]
    return node


def set_path(data: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A deep copy of `data` with the entry at `path` replaced (it must exist)."""
    out = copy.deepcopy(data)
    *parents, leaf = path.split(".")
    node = out
    for part in parents:
        node = node[part]
    node[leaf] = value
    return out


class FamilySpec(StrictModel):
    """A family request (see module docstring). Build with `parse_family`."""

    spec: dict[str, Any]
    param: Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)+$")]
    values: Annotated[list[float], Field(min_length=1, max_length=200)]
    strategy: Literal["independent", "continuation"] = "independent"
    start_from: Literal["low", "high", "both", "middle"] = Field("both", alias="from")
    warm: WarmConfig = WarmConfig()
    leave_out: Annotated[list[float], Field(max_length=200)] = []
    # A reduced run searches k coordinates: CMA-ES needs at least 2 (optim.cmaes.MIN_DIMENSION).
    k: Annotated[int, Field(ge=2, le=16)] = 3
    seed: Annotated[int, Field(ge=0, lt=2**31)] = 1
    reduced_start: Literal["neighbours", "centre"] = "neighbours"
    switch_threshold: Annotated[float, Field(gt=0.0, le=1.0)] = SWITCH_THRESHOLD

    model_config = {**StrictModel.model_config, "populate_by_name": True}

    #: The base spec and the member specs, parsed once per FamilySpec.
    _base: Any = PrivateAttr(default=None)
    _members: dict[tuple[float, str], TaskSpec] = PrivateAttr(default_factory=dict)

    @model_validator(mode="after")
    def _check(self) -> FamilySpec:
        try:
            base = parse_spec(self.spec, "spec")
        except SpecError as err:
            raise ValueError(str(err)) from None
        self._base = base
        dumped = base.model_dump(mode="json")
        try:
            current = get_path(dumped, self.param)
        except KeyError as err:
            raise ValueError(f"param: {self.param!r} is not in the spec (no {err.args[0]!r})"
                             ) from None
        if isinstance(current, bool) or not isinstance(current, int | float):
            raise ValueError(f"param: {self.param!r} must name a number in the spec, it holds "
                             f"{type(current).__name__}")
        if len(set(self.values)) != len(self.values):
            dup = sorted({v for v in self.values if self.values.count(v) > 1})
            raise ValueError(f"values: must be distinct; repeated: {', '.join(map(_vid, dup))}")
        for i, v in enumerate(self.values):
            try:
                parse_spec(set_path(dumped, self.param, v), "spec")
            except SpecError as err:
                raise ValueError(f"values[{i}]: {self.param} = {_vid(v)} is refused: "
                                 f"{str(err).removeprefix('spec: ')}") from None
        for i, v in enumerate(self.leave_out):
            if v not in self.values:
                raise ValueError(f"leave_out[{i}]: {_vid(v)} is not one of the values")
        if len(set(self.leave_out)) != len(self.leave_out):
            raise ValueError("leave_out: must be distinct")
        need = self.k + 2 if self.leave_out else self.k + 1
        if len(self.values) < need:
            besides = " besides the left-out one" if self.leave_out else ""
            raise ValueError(f"k: {self.k} components need at least {need} values (a basis "
                             f"of k + 1 members{besides}), got {len(self.values)}")
        return self

    # -- derived -------------------------------------------------------------------------------
    @property
    def base(self) -> TaskSpec:
        if self._base is None:
            self._base = parse_spec(self.spec, "spec")
        return self._base

    @property
    def family(self) -> str:
        return self.base.family_name

    @property
    def leaf(self) -> str:
        """The parameter's last path part (`mass` for `task.mass`): the key in tables."""
        return self.param.rsplit(".", 1)[-1]

    @property
    def sorted_values(self) -> list[float]:
        return sorted(float(v) for v in self.values)

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json", by_alias=True)


def _format_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        where = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        lines.append(f"{where}: {msg}" if where else msg)
    return "; ".join(lines)


def parse_family(data: Any, source: str = "family") -> FamilySpec:
    """Validate a mapping into a FamilySpec; FamilyError naming each bad field and its rule."""
    if not isinstance(data, Mapping):
        raise FamilyError(f"{source}: a family must be a mapping, got {type(data).__name__}")
    try:
        return FamilySpec.model_validate(dict(data))
    except ValidationError as err:
        raise FamilyError(f"{source}: {_format_error(err)}") from None


# ---- member specs -------------------------------------------------------------------------------
#: Roles of a run's spec: the main rules (members from the flat spline, references, reduced
#: runs) or the warm rules (continuation members after a chain's first).
MAIN, WARM = "main", "warm"


def member_spec(fs: FamilySpec, value: float, role: str = MAIN) -> TaskSpec:
    """The base spec with `param` = value, named `<family>_<leaf><value>` in the family; with
    role WARM its optimizer step and stopping rules are `fs.warm`'s. Parsed once per family
    spec, value and role."""
    key = (float(value), role)
    hit = fs._members.get(key)
    if hit is None:
        hit = fs._members[key] = _member_spec(fs, value, role)
    return hit


def _member_spec(fs: FamilySpec, value: float, role: str) -> TaskSpec:
    data = set_path(fs.base.model_dump(mode="json"), fs.param, float(value))
    data["family"] = fs.family
    data["name"] = f"{fs.family}_{fs.leaf}{_vid(value)}"[:100]
    if role == WARM:
        main = OptimizeConfig.model_validate(data["optimize"])
        warm = fs.warm.model_dump(mode="json")
        # a warm-started member never gets more evaluations than a cold one
        warm["max_evaluations"] = min(warm["max_evaluations"], main.max_evaluations)
        data["optimize"] = {**main.model_dump(mode="json"), **warm}
    return parse_spec(data, f"family member {fs.param} = {_vid(value)}")


# ---- the plan -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class FamilyRun:
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
    return f"member-{direction}-{_vid(value)}"


def plan_runs(fs: FamilySpec) -> list[FamilyRun]:
    """Every run of the family, in a deterministic order (see module docstring)."""
    runs: list[FamilyRun] = []
    heads: dict[float, str] = {}
    for direction, values, start in chains(fs):
        prev = None if start is None else member_run_id("mid", start)
        for i, v in enumerate(values):
            rid = member_run_id(direction, v)
            # The rest of the chain (this run included) waits on this run: longest first.
            runs.append(FamilyRun(rid, MEMBER, v, prev, () if prev is None else (prev,),
                                  priority=100 + len(values) - i))
            if prev is None:
                heads.setdefault(v, rid)
            prev = rid
    member_ids = tuple(r.id for r in runs)
    for v in fs.leave_out:
        if float(v) not in heads:
            runs.append(FamilyRun(f"reference-{_vid(v)}", REFERENCE, float(v), priority=50))
    for v in fs.leave_out:
        runs.append(FamilyRun(f"reduced-{_vid(v)}", REDUCED, float(v), needs=member_ids,
                              priority=10))
    runs.append(FamilyRun(PROBES, PROBES, None, needs=member_ids, priority=0))
    return runs


def ready_runs(
    runs: Sequence[FamilyRun], done: Collection[str], running: Collection[str] = ()
) -> list[FamilyRun]:
    """Runs not done nor running whose needs are all done, highest priority first (ties: plan
    order)."""
    ready = [r for r in runs
             if r.id not in done and r.id not in running and all(n in done for n in r.needs)]
    order = {r.id: i for i, r in enumerate(runs)}
    return sorted(ready, key=lambda r: (-r.priority, order[r.id]))


def reference_run_id(fs: FamilySpec, runs: Sequence[FamilyRun], value: float) -> str:
    """The cold full-space run at `value`: a cold member there, else its reference run."""
    for r in runs:
        if r.kind == MEMBER and r.cold and r.value == value:
            return r.id
    return f"reference-{_vid(value)}"


def family_members(
    runs: Sequence[FamilyRun], results: Mapping[str, OptimizationResult]
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
    fs: FamilySpec, run: FamilyRun, runs: Sequence[FamilyRun],
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
    members = {v: res for v, (_, res) in family_members(runs, results).items()}
    basis = leave_one_out_basis(fs, members, run.value)
    spec = member_spec(fs, run.value)
    if fs.reduced_start == "centre":
        return RunStart(spec, None, basis, "box centre")
    got = interpolated_params(fs, members, run.value)
    if got is not None:
        x0, lo, hi = got
        return RunStart(spec, x0, basis, f"interpolated {_vid(lo)}-{_vid(hi)}")
    others = [v for v in members if v != run.value]
    near = min(others, key=lambda v: (abs(v - run.value), v))
    return RunStart(spec, np.asarray(members[near].params, dtype=float), basis,
                    f"member {_vid(near)}")


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


# ---- checks -------------------------------------------------------------------------------------
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
    switch: bool
    knot_shift: float | None  # s, largest knot-time change from the previous member


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


def family_checks(
    fs: FamilySpec,
    results: Mapping[str, OptimizationResult],
    probes: Mapping[float, EvalOutcome] | None = None,
    runs: Sequence[FamilyRun] | None = None,
) -> FamilyChecks:
    """The checks as a pure function of the finished runs' results (run id -> result) and the
    probes' outcomes (value -> outcome of the interpolated CMRT there)."""
    runs = list(runs) if runs is not None else plan_runs(fs)
    chosen = family_members(runs, results)
    members = {v: res for v, (_, res) in chosen.items()}
    probes = probes or {}
    window = fs.base.optimize.window

    recon = reconstruction_errors(fs.k, members)
    rows_m: list[MemberRow] = []
    prev: OptimizationResult | None = None
    for v in sorted(members):
        rid, r = chosen[v]
        shift = None if prev is None else float(np.max(np.abs(
            np.asarray(r.knot_times) - np.asarray(prev.knot_times))))
        e = recon.get(v)
        rows_m.append(MemberRow(v, rid, r.objective, r.fell, r.task_success,
                                r.baseline_objective, r.evaluations, r.stop_rule, e,
                                e is not None and e > fs.switch_threshold, shift))
        prev = r

    probe_rows: dict[float, ProbeRow] = {}
    for v, (_p, lo, hi) in ((v, (p, lo, hi)) for v, p, lo, hi in probe_points(fs, members)):
        out = probes.get(v)
        if out is None:
            continue
        m = members[v].objective
        probe_rows[v] = ProbeRow(v, lo, hi, out.objective, out.fell, out.task_success, m,
                                 out.objective / m - 1.0)

    basis = None
    variance: list[float] = []
    if len(members) >= fs.k + 1:
        try:
            b = build_basis([members[v] for v in sorted(members)], k=fs.k, family=fs.family)
            basis, variance = b.to_dict(), [float(x) for x in b.variance_explained]
        except BasisError:  # every member the same CMRT: nothing to reduce (basis None)
            pass

    rows: list[Table2Row] = []
    for v in fs.leave_out:
        v = float(v)
        red = results.get(f"reduced-{_vid(v)}")
        cold = results.get(reference_run_id(fs, runs, v))
        if red is None or cold is None or v not in members:
            continue
        b = leave_one_out_basis(fs, members, v)
        start = run_start(fs, next(r for r in runs if r.id == f"reduced-{_vid(v)}"), runs,
                          results).start
        member = members[v]
        ref_src = "cold" if cold.objective < member.objective else "member"
        ref = min(cold.objective, member.objective)
        c_conv, r_conv = converged_at(cold.history), converged_at(red.history)
        c_rule, r_rule = rule_converged_at(cold, window), rule_converged_at(red, window)
        c_full = evaluations_to_reach(cold.history, cold.objective)
        r_full = evaluations_to_reach(red.history, cold.objective)
        rows.append(Table2Row(
            value=v, k=fs.k, basis_members=len(members) - 1,
            variance_explained=[float(x) for x in b.variance_explained[: fs.k]],
            member_objective=member.objective, interpolated=probe_rows.get(v),
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
        ))

    def median(key: str) -> float | None:
        xs = [getattr(r, key) for r in rows if getattr(r, key) is not None]
        return float(np.median(xs)) if xs else None

    medians = {key: median(key) for key in ("speedup_converged", "speedup_rule_converged",
                                             "speedup_to_full")}
    medians["worst_relative_error"] = max((r.relative_error for r in rows), default=None)
    return FamilyChecks(fs.k, variance, basis, rows_m, sorted(probe_rows.values(),
                        key=lambda p: p.value), rows, fs.switch_threshold, medians)


# ---- report -------------------------------------------------------------------------------------
def curve_of(result: OptimizationResult) -> list[list[float]]:
    """[evaluations, best so far] after each generation."""
    return [[int(h["evaluations"]), float(h["best_so_far"])] for h in result.history]


def family_report(
    fs: FamilySpec,
    results: Mapping[str, OptimizationResult],
    probes: Mapping[float, EvalOutcome] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The family's JSON document: spec, members, every run, basis and checks."""
    runs = plan_runs(fs)
    chosen = family_members(runs, results)
    checks = family_checks(fs, results, probes, runs)
    members = []
    for v in sorted(chosen):
        rid, r = chosen[v]
        members.append({
            "value": v, "run": rid, "name": r.name, "objective": r.objective, "fell": r.fell,
            "fall_direction": r.fall_direction, "task_success": r.task_success,
            "baseline_objective": r.baseline_objective, "baseline_fell": r.baseline_fell,
            "evaluations": r.evaluations, "stop_rule": r.stop_rule, "params": r.params,
            "knot_times": r.knot_times, "values": r.values,
            "vertical_values": r.vertical_values, "curve": curve_of(r),
        })
    run_rows = []
    for r in runs:
        res = results.get(r.id)
        if res is None or r.kind == PROBES:
            continue
        run_rows.append({"id": r.id, "kind": r.kind, "value": r.value,
                         "warm_from": r.warm_from, "objective": res.objective,
                         "fell": res.fell, "task_success": res.task_success,
                         "evaluations": res.evaluations, "stop_rule": res.stop_rule,
                         "wall_seconds": res.wall_seconds, "basis_id": res.basis_id,
                         "curve": curve_of(res)})
    return {"format": FAMILY_FORMAT, "family": fs.family, "param": fs.param,
            "spec": fs.to_dict(), "members": members, "runs": run_rows,
            "basis": checks.basis, "checks": checks.to_dict(), **dict(extra or {})}


def _f(x: float | None, fmt: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def format_tables(report: Mapping[str, Any]) -> str:
    """Markdown tables of a `family_report`: members, interpolation, Table 2 rows."""
    c = report["checks"]
    leaf = report["param"].rsplit(".", 1)[-1]
    out = [f"| {leaf} | run | no CMRT | optimised | fell | task | evaluations | stop rule | "
           "recon. error | knot shift (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for m in c["members"]:
        flag = " **switch**" if m["switch"] else ""
        out.append(f"| {m['value']:g} | {m['run']} | {m['baseline_objective']:.3f} | "
                   f"{m['objective']:.3f} | {m['fell']} | {m['task_success']} | "
                   f"{m['evaluations']} | {m['stop_rule']} | "
                   f"{_f(m['reconstruction_error'])}{flag} | {_f(m['knot_shift'], '.2f')} |")
    ve = c["variance_explained"]
    out.append(f"\nbasis: k = {c['k']}, variance explained per component "
               f"{', '.join(f'{x:.1%}' for x in ve[: c['k']])} (sum "
               f"{sum(ve[: c['k']]):.1%}); switch threshold {c['switch_threshold']:g}; "
               f"flagged: {', '.join(f'{v:g}' for v in c['switches']) or 'none'}")
    out += ["", f"| {leaf} | from | interpolated | fell | task | optimised there | excess |",
            "|---|---|---|---|---|---|---|"]
    for p in c["probes"]:
        out.append(f"| {p['value']:g} | {p['lower']:g}, {p['upper']:g} | {p['objective']:.3f}"
                   f" | {p['fell']} | {p['task_success']} | {p['member_objective']:.3f} | "
                   f"{p['excess']:+.1%} |")
    out += ["", f"| {leaf} | var. expl. (k) | reduced: obj (evals; conv. 1 % / rule) | "
            "reference (source) | cold full: obj (evals; conv. 1 % / rule) | rel. error | "
            "speed-up: 1 % / rule / to full obj |", "|---|---|---|---|---|---|---|"]
    for r in c["rows"]:
        out.append(
            f"| {r['value']:g} | {sum(r['variance_explained']):.1%} | "
            f"{r['reduced_objective']:.3f}{' (fell)' if r['reduced_fell'] else ''} "
            f"({r['reduced_evaluations']}; {r['reduced_converged_at']} / "
            f"{r['reduced_rule_converged_at']}) | {r['reference_objective']:.3f} "
            f"({r['reference_source']}) | {r['cold_objective']:.3f} ({r['cold_evaluations']}; "
            f"{r['cold_converged_at']} / {r['cold_rule_converged_at']}) | "
            f"{r['relative_error']:+.1%} | {_f(r['speedup_converged'], '.2f')}x / "
            f"{_f(r['speedup_rule_converged'], '.2f')}x / {_f(r['speedup_to_full'], '.2f')}x |")
    md = c["medians"]
    if c["rows"]:
        out.append(f"\nmedian speed-up: 1 % {_f(md['speedup_converged'], '.2f')}x, rule "
                   f"{_f(md['speedup_rule_converged'], '.2f')}x, to full objective "
                   f"{_f(md['speedup_to_full'], '.2f')}x; worst relative error "
                   f"{md['worst_relative_error']:+.1%}")
    return "\n".join(out)


__all__ = [
    "CONVERGED_WITHIN",
    "FAMILY_FORMAT",
    "MAIN",
    "MEMBER",
    "PROBES",
    "REDUCED",
    "REFERENCE",
    "SWITCH_THRESHOLD",
    "WARM",
    "FamilyChecks",
    "FamilyError",
    "FamilyRun",
    "FamilySpec",
    "RunStart",
    "Table2Row",
    "WarmConfig",
    "chains",
    "converged_at",
    "evaluations_to_reach",
    "family_checks",
    "family_members",
    "family_report",
    "format_tables",
    "interpolated_params",
    "leave_one_out_basis",
    "member_spec",
    "parse_family",
    "plan_runs",
    "probe_points",
    "ready_runs",
    "reconstruction_errors",
    "run_start",
]
