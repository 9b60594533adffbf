"""What the library serves at a task parameter, and what it can stand behind.

An answer says what it is: its `source` (`member`: a CMRT the library holds, optimised at
that value or served as it is at a neighbouring one; `interpolated`: the curve between the two
neighbouring members; `refined`: a member a refinement job optimised at that value; `robust`:
a robust CMRT whose range covers the value, `robust` naming it and its range), the
members it was built from, whether a strategy switch lies between them, and, once simulated
(`verify`), its outcome on the spec of the query, kept in the library so that the next
identical query costs nothing.

The rules, in order:
  * **no average across a switch**: two neighbours whose spline parameters lie further apart
    than `SWITCH_DISTANCE` are two ways of doing the task; their average is neither, so the
    nearer member is served instead and the answer says why;
  * **verify**: the served CMRT is simulated on the spec at the query's value. An answer that
    falls, fails its task or is weak (its objective more than `WEAK_MARGIN` above the library's
    own prediction, the neighbours' objectives interpolated) is not served as good: the
    neighbouring members are simulated there too (and, across a switch, their average: tried,
    never served unsimulated) and the best that stands is served; when none stands the answer
    says so plainly and offers a refinement;
  * **refine** (`refine_job`): an optimisation in the family's PCA basis started at the best
    answer, under a small budget; its result joins the library as a member of the family.

Pure of the web and the queue: the service and the command line call it; the simulation is a
callable handed in (the what-if process pool on the service).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from application import jobs
from application.admission import Budget, default_popsize
from application.errors import InvalidRequest
from application.library import (
    MAX_MEMBERS,
    SWITCH_DISTANCE,
    LibraryCmrt,
    interpolated_at,
    nearer,
    params_distance,
)
from cmrt.canonical import text_hash
from cmrt.defaults import DEFAULT_SEED
from cmrt.lru import LRU
from cmrt.settings import Settings
from optim.errors import InterpolationError
from optim.interpolate import InterpolatedCmrt
from optim.spline import CmrtSpline, encode, sample_curve
from sim.errors import SpecError
from sim.spec import CanonicalSpec, TaskSpec, parse_canonical, parse_spec
from store import CmrtRecord, JobRecord, JobStart, NotFound, Repository

#: A verified answer whose objective exceeds the library's prediction (the neighbours'
#: objectives interpolated at the value) by more than this fraction is weak: the neighbouring
#: members are tried there too.
WEAK_MARGIN = 0.05
#: A refinement's stopping rules: at most `REFINE_MAX_EVALUATIONS` evaluations in whole
#: generations (the paper's use of a basis: a new task instance in a few generations), ending
#: earlier when the best improved less than `REFINE_IMPROVEMENT` over the last `REFINE_WINDOW`
#: evaluations.
REFINE_MAX_EVALUATIONS = 150
REFINE_WINDOW = 35
REFINE_IMPROVEMENT = 0.01
#: A refinement's CMA-ES step in the basis's box (it starts at an answer, not from nothing).
REFINE_SIGMA0 = 0.1
#: What the library's sources are called in an answer.
SOURCES = ("member", "interpolated", "refined", "robust")

#: simulate(spec document, CMRT parameters) -> {"status": "done" | "failed", "objective",
#: "fell", "fall_direction", "task_success", "cpu_seconds", "error"}.
Simulate = Callable[[dict[str, Any], list[float]], dict[str, Any]]


class AnswerError(InvalidRequest):
    """A query the library cannot answer; the message starts with the field it is about."""


@dataclass(frozen=True)
class LibraryQuery:
    """Ask the library for its answer at task parameters: `parameters` (library keys such as
    `mass`, or spec paths such as `task.mass`) name the point, `along` the interpolated one
    when there are several (the others must match exactly); outside the stored range only
    with `extrapolate`. `where` starts the messages about the parameters (`parameters: ` in a
    request body). InvalidRequest when the parameters cannot name one point."""

    family: str
    parameters: Mapping[str, float]
    along: str | None = None
    extrapolate: bool = False
    where: str = ""

    def __post_init__(self) -> None:
        if not self.parameters:
            raise InvalidRequest(f"{self.where}a task parameter to interpolate at is required, "
                                 "e.g. mass=60")
        if self.along is None and len(self.parameters) > 1:
            raise InvalidRequest("along: required when several task parameters are given")
        if self.along is not None and self.along not in self.parameters:
            raise InvalidRequest(f"along: {self.along!r} is not among the given parameters")


@dataclass(frozen=True)
class Refine:
    """Refine the library's answer at `query` in the family's PCA basis (the newest, or
    `basis_id`) under `max_evaluations`."""

    query: LibraryQuery
    basis_id: str | None = None
    max_evaluations: int = REFINE_MAX_EVALUATIONS
    seed: int = DEFAULT_SEED


@dataclass(frozen=True)
class Answer:
    """What the library serves at a task parameter, and what it is (the module docstring):
    the served CMRT (`spline`, its curve fields read from it) with its provenance, the
    neighbours' check and, once simulated, its outcome. `interpolation` is the neighbours'
    interpolation, whichever CMRT is served."""

    family: str
    key: str
    value: float
    note: str | None
    source: str
    members: list[str]
    #: {id, <key>: value, objective, task_parameters} of each neighbour, lower first.
    neighbours: list[dict[str, Any]]
    weight: float
    exact: bool
    extrapolated: bool
    switch: dict[str, Any] | None
    predicted_objective: float
    robust: dict[str, Any] | None
    spline: CmrtSpline
    interpolation: CmrtSpline
    message: str
    verified: bool = False
    verdict: str = "unverified"
    outcome: dict[str, Any] | None = None
    tried: list[dict[str, Any]] = field(default_factory=list)

    @property
    def length(self) -> float:
        return float(self.spline.length)

    @property
    def knot_times(self) -> list[float]:
        return [float(v) for v in self.spline.knot_times]

    @property
    def values(self) -> list[float]:
        return [float(v) for v in self.spline.values]

    @property
    def vertical_values(self) -> list[float] | None:
        vy = self.spline.vertical_values
        return None if vy is None else [float(v) for v in vy]

    @property
    def curve(self) -> dict[str, list[float]]:
        return sample_curve(self.spline)


@dataclass(frozen=True)
class Refinement:
    """A submitted refinement: its job, the budget admitted and the answer it started from."""

    job: JobRecord
    budget: Budget
    answer: Answer


@dataclass(frozen=True)
class _Candidate:
    """A CMRT the library could serve at the query's value."""

    source: str
    members: list[CmrtRecord]
    spline: CmrtSpline

    @property
    def ids(self) -> list[str]:
        return [m.id for m in self.members]


def library_parameter(repo: Repository, family: str, name: str) -> tuple[str, str | None]:
    """The library key `name` means in `family` (`mass` as it is; a spec path such as
    `task.mass` translated), and a note when it was translated. AnswerError naming `name`
    when the family has no such parameter."""
    keys = [k for k in repo.cmrt_keys(family) if k.has_spec]
    if not keys:
        raise AnswerError(f"family: no library CMRTs of family {family!r}")
    if any(name in k.task_parameters for k in keys):
        return name, None
    spec = parse_spec(repo.get_cmrt(keys[0].id).spec, f"library CMRT {keys[0].id}")
    try:
        key = spec.library_key(name)
    except ValueError as err:
        raise AnswerError(f"{name}: {err}") from None
    return key, f"{name} is the library parameter {key!r}"


def serve(repo: Repository, query: LibraryQuery, simulate: Simulate | None = None
          ) -> Answer:
    """The library's answer to `query` (module docstring); simulated and checked when
    `simulate` is given. AnswerError when the library cannot answer there (range, family,
    parameter, a spec the value makes invalid)."""
    return _answered(repo, query, simulate)[0]


def _answered(repo: Repository, q: LibraryQuery, simulate: Simulate | None
              ) -> tuple[Answer, list[CmrtRecord], dict[str, float]]:
    """`serve`'s answer, the neighbouring library CMRTs it read and the query's other
    (matched) parameters."""
    along = q.along or next(iter(q.parameters))
    notes, named = [], {}
    for name, v in q.parameters.items():
        key = name
        if "." in name:  # a spec path (task.mass): the library names it by its key
            try:
                key, note = library_parameter(repo, q.family, name)
            except AnswerError as err:
                raise AnswerError(f"{q.where}{err}") from None
            if note:
                notes.append(note)
        if key in named:
            raise AnswerError(f"{q.where}{name}: given twice ({key})")
        named[key] = v
        if name == along:
            along = key
    value = named.pop(along)
    try:
        answer, recs = _serve(repo, q.family, along, value, filters=named,
                              extrapolate=q.extrapolate, simulate=simulate,
                              note="; ".join(notes) or None)
    except InterpolationError as err:
        raise AnswerError(str(err)) from None
    return answer, recs, named


def _serve(
    repo: Repository,
    family: str,
    key: str,
    value: float,
    *,
    filters: Mapping[str, float],
    extrapolate: bool,
    simulate: Simulate | None,
    note: str | None,
) -> tuple[Answer, list[CmrtRecord]]:
    """The answer at `key` = `value` and the neighbouring library CMRTs it read."""
    cover = robust_cover(repo, family, key, value, filters)
    try:
        got, recs = interpolated_at(repo, family, key, value, filters=filters,
                                    extrapolate=extrapolate)
    except InterpolationError:
        if cover is None:
            raise
        got, recs = _robust_only(cover[0], key, value), [cover[0]]
    switch = _switch(recs, key) if not got.exact and len(recs) == 2 else None
    interp = got.spline()
    primary, why = _primary(repo, got, recs, key, value, cover, switch, interp)
    answer = Answer(
        family=family, key=key, value=value, note=note, source=primary.source,
        members=primary.ids,
        neighbours=[{"id": r.id, key: v, "objective": r.objective,
                     "task_parameters": r.task_parameters}
                    for r, v in zip(recs, (got.lower_value, got.upper_value), strict=False)],
        weight=got.weight, exact=got.exact, extrapolated=got.extrapolated, switch=switch,
        predicted_objective=_predicted(got, recs),
        robust=None if cover is None else {"id": cover[0].id, **cover[1]},
        spline=primary.spline, interpolation=interp,
        message=why + "; not simulated (verify=true simulates it once)")
    if simulate is None:
        return answer, recs
    spec = _spec_at(nearer(recs, key, value), key, value, filters)
    cands = [primary]
    tried = [_verify(repo, family, spec, primary, simulate)]
    if not _good(tried[0], answer.predicted_objective):
        # the neighbours as they are; across a switch also their average, which is never
        # served unsimulated there but may, simulated, be the best the library has
        others = [_Candidate("member", [r], _member_spline(r))
                  for r in sorted(recs, key=lambda r: abs(r.task_parameters[key] - value))]
        if primary.source != "interpolated" and not got.exact and len(recs) == 2:
            others.append(_Candidate("interpolated", recs, interp))
        for c in others:
            if c.source == primary.source and c.ids == primary.ids:
                continue
            cands.append(c)
            tried.append(_verify(repo, family, spec, c, simulate))
    i = min(range(len(tried)), key=lambda j: _rank(tried[j]))
    best, verdict = tried[i], _verdict(tried[i], answer.predicted_objective)
    return replace(answer, source=cands[i].source, members=cands[i].ids,
                   spline=cands[i].spline, verified=True, outcome=best["outcome"],
                   tried=tried, verdict=verdict,
                   message=_message(why, verdict, answer.predicted_objective, best, tried,
                                    key, value)), recs


def refine(repo: Repository, settings: Settings, cmd: Refine) -> Refinement:
    """Submit a refinement (`Refine`): a job searching the family's PCA basis, started at the
    best answer the library has there (a verified one when the library kept one), under its
    evaluations. Its result joins the library as a member. AnswerError naming `basis` when
    the family has none, and as `serve`; the job's refusals as `jobs.submit_job`."""
    answer, recs, filters = _answered(repo, cmd.query, None)
    family, key, value = answer.family, answer.key, answer.value
    if cmd.basis_id is None:
        bases, _ = repo.list_bases(family, limit=1)
        if not bases:
            raise AnswerError(
                f"basis: family {family!r} has no PCA basis to refine in; build one first "
                f"(POST /bases with {{\"family\": \"{family}\"}}, or `cmrt library basis --family "
                f"{family}`)")
        basis = bases[0]
    else:
        try:
            basis = repo.get_basis(cmd.basis_id)
        except NotFound:
            raise AnswerError(f"basis: no basis {cmd.basis_id!r}") from None
        if basis.family != family:
            raise AnswerError(f"basis: {cmd.basis_id!r} is not a basis of family {family!r}")
    spec = _spec_at(nearer(recs, key, value), key, value, filters)
    served = _Candidate(answer.source, [r for r in recs if r.id in answer.members],
                        answer.spline)
    cands = [served] + [_Candidate("member", [r], _member_spline(r)) for r in recs]
    if not answer.exact and len(recs) == 2:
        cands.append(_Candidate("interpolated", recs, answer.interpolation))
    start_from = _best_cached(repo, spec, cands) or served
    # Whole generations within the budget: CMA-ES stops between generations, so a cap that is
    # not a multiple of the population would be passed by up to one generation.
    popsize = spec.spec.optimize.popsize or default_popsize(basis.k)
    cap = min(cmd.max_evaluations, spec.spec.optimize.max_evaluations)
    cap = max(popsize, cap // popsize * popsize)
    typed = spec.spec.model_copy(update={"optimize": spec.spec.optimize.model_copy(update={
        "threshold": None, "min_evaluations": 0, "max_evaluations": cap,
        "window": REFINE_WINDOW, "improvement": REFINE_IMPROVEMENT})})
    canonical = parse_canonical(typed.model_dump(mode="json"), "spec")
    x0 = [float(v) for v in encode(canonical.spec, start_from.spline)]
    start = JobStart(
        (f"refinement in basis {basis.id} at {key} = {value:g}, started at the "
         f"{start_from.source} answer of " + ", ".join(start_from.ids)),
        tuple(x0), REFINE_SIGMA0, tuple(start_from.ids), kind="refine")
    job, budget = jobs.submit_job(repo, settings, canonical, seed=cmd.seed, basis_id=basis.id,
                                  start=start)
    return Refinement(job, budget, answer)


# ---- the pieces ---------------------------------------------------------------------------
def robust_cover(repo: Repository, family: str, key: str, value: float,
                 filters: Mapping[str, float] | None = None
                 ) -> tuple[CmrtRecord, dict[str, Any]] | None:
    """The robust library CMRT (`sim.robust`) whose range covers `key` = `value` (and whose
    other task parameters equal `filters`), the one with the lowest objective, with its range
    {path, range, samples, aggregate}; None when no robust CMRT covers the value. The robust
    block is read from each entry's stored spec (kept by the store after the first read)."""
    best: tuple[CmrtRecord, dict[str, Any]] | None = None
    for k in repo.cmrt_keys(family)[:MAX_MEMBERS]:
        if not k.has_spec or key not in k.task_parameters:
            continue
        if any(abs(k.task_parameters.get(n, math.nan) - v) > 1e-9 * max(1.0, abs(v))
               for n, v in (filters or {}).items()):
            continue
        rec = repo.get_cmrt(k.id)
        rb = ((rec.spec or {}).get("optimize") or {}).get("robust")
        if not rb:
            continue
        path = _parameter_paths(rec)[key]
        lo, hi = rb["vary"].get(path, (math.nan, math.nan))
        if lo <= value <= hi and (best is None or rec.objective < best[0].objective):
            best = (rec, {"path": path, "range": [lo, hi], "samples": rb["samples"],
                          "aggregate": rb["aggregate"]})
    return best


#: Library parameter -> spec path of robust CMRTs by id (an entry never changes): a query
#: parses a robust CMRT's spec once per process, not at every answer.
_PATHS_KEPT = 1024
_PATHS: LRU[str, dict[str, str]] = LRU(_PATHS_KEPT)


def _parameter_paths(rec: CmrtRecord) -> dict[str, str]:
    return _PATHS.get_or_make(
        rec.id, lambda: parse_spec(rec.spec, f"library CMRT {rec.id}").parameter_paths())


def _robust_only(rec: CmrtRecord, key: str, value: float) -> InterpolatedCmrt:
    """The robust CMRT as the one neighbour when it alone covers the value (no two members
    bracket it)."""
    m, v = LibraryCmrt.of(rec), rec.task_parameters[key]
    vy = None if m.vertical_values is None else np.asarray(m.vertical_values)
    return InterpolatedCmrt(key, value, m.length, np.asarray(m.knot_times), np.asarray(m.values),
                            vy, rec.id, rec.id, v, v, weight=0.0, extrapolated=False,
                            exact=False)


def _primary(repo: Repository, got: InterpolatedCmrt, recs: list[CmrtRecord], key: str,
             value: float, cover: tuple[CmrtRecord, dict[str, Any]] | None,
             switch: dict[str, Any] | None, interp: CmrtSpline) -> tuple[_Candidate, str]:
    """The answer served first, and why: the member optimised at the value, a robust CMRT
    covering it, the nearer member across a switch, or the neighbours' interpolation."""
    near = nearer(recs, key, value)
    if got.exact:
        primary = _Candidate(_member_source(repo, recs[0]), [recs[0]], _member_spline(recs[0]))
        why = f"the library holds a CMRT optimised at {key} = {value:g}"
    elif cover is not None:
        primary = _Candidate("robust", [cover[0]], _member_spline(cover[0]))
        rb = cover[1]
        why = (f"the robust CMRT {cover[0].id} was optimised for {key} from "
               f"{rb['range'][0]:g} to {rb['range'][1]:g} ({rb['samples']} variants, "
               f"{rb['aggregate']} objective)")
    elif switch is not None and switch["detected"]:
        primary = _Candidate("member", [near], _member_spline(near))
        why = (f"a strategy switch lies between the members at {key} = "
               f"{switch['between'][0][key]:g} and {switch['between'][1][key]:g} (their "
               f"CMRTs are {switch['distance']:.2f} apart, above {SWITCH_DISTANCE:g}): the "
               f"nearer member ({key} = {near.task_parameters[key]:g}) is served, not their "
               "average")
    else:
        primary = _Candidate("interpolated", recs, interp)
        why = (f"interpolated between the members at {key} = "
               + " and ".join(f"{r.task_parameters[key]:g}" for r in recs))
    return primary, why


def _member_spline(rec: CmrtRecord) -> CmrtSpline:
    return LibraryCmrt.of(rec).spline()


def _member_source(repo: Repository, rec: CmrtRecord) -> str:
    """`refined` for a member a refinement job made, else `member`."""
    if rec.job_id is None:
        return "member"
    try:
        start = repo.get_job(rec.job_id).start
    except NotFound:
        return "member"
    return "refined" if start is not None and start.kind == "refine" else "member"


def _switch(recs: list[CmrtRecord], key: str) -> dict[str, Any]:
    """The library's own check of two neighbours: the RMS distance of their spline parameters
    and the largest change of a knot time (s)."""
    distance = params_distance(recs[0], recs[1])
    shift = max((abs(x - y) for x, y in zip(recs[0].knots, recs[1].knots, strict=False)),
                default=0.0)
    return {"detected": bool(distance > SWITCH_DISTANCE), "distance": distance,
            "threshold": SWITCH_DISTANCE, "knot_shift": float(shift),
            "between": [{"id": r.id, key: r.task_parameters[key]} for r in recs]}


def _predicted(got: InterpolatedCmrt, recs: list[CmrtRecord]) -> float:
    """The neighbours' objectives interpolated at the value (the library's own prediction)."""
    if got.exact or len(recs) < 2:
        return float(recs[0].objective)
    w = float(got.weight)
    return float((1.0 - w) * recs[0].objective + w * recs[1].objective)


#: Query specs this process has built (library entries never change, so a member's id, the
#: parameter and the value name one spec): a kept answer is served without parsing a spec.
#: How many query specs are kept (a few kB each).
SPECS_AT_CACHED = 1024
_SPECS_AT: LRU[tuple[Any, ...], CanonicalSpec] = LRU(SPECS_AT_CACHED)


def _spec_at(rec: CmrtRecord, key: str, value: float,
             filters: Mapping[str, float] | None) -> CanonicalSpec:
    """The spec of the query: member `rec`'s spec with `key` (and the filters) set."""
    cache_key = (rec.id, key, float(value), tuple(sorted((filters or {}).items())))
    got = _SPECS_AT.get(cache_key)  # the service answers on several threads: LRU locks
    if got is not None:
        return got
    spec: TaskSpec = parse_spec(rec.spec, f"library CMRT {rec.id}")
    doc = spec.with_parameter(key, value)
    doc["optimize"].pop("robust", None)  # the query is one scene, not a robust CMRT's range
    for name, v in (filters or {}).items():
        doc = parse_spec(doc).with_parameter(name, v)
    try:
        got = parse_canonical(doc, "spec")
    except SpecError as err:
        raise AnswerError(f"{key}: {value:g} makes the task invalid: {err}") from None
    _SPECS_AT.put(cache_key, got)
    return got


def _params_hash(params: list[float]) -> str:
    return text_hash(json.dumps([float(v) for v in params]))


def _verify(repo: Repository, family: str, spec: CanonicalSpec, c: _Candidate,
            simulate: Simulate) -> dict[str, Any]:
    """Candidate `c` simulated on `spec`: the library's kept outcome, or one simulation (then
    kept)."""
    params = [float(v) for v in encode(spec.spec, c.spline)]
    ph = _params_hash(params)
    rec = repo.get_verification(spec.hash, ph)
    cached = rec is not None
    if rec is None:
        got = simulate(spec.document, params)
        outcome = {k: got.get(k) for k in ("status", "objective", "fell", "fall_direction",
                                           "task_success", "cpu_seconds", "error")}
        if outcome["status"] == "done" and outcome.get("objective") is None:
            outcome.update(status="failed", error="the simulation gave no objective")
        rec = repo.add_verification(family=family, spec_hash=spec.hash, params_hash=ph,
                                    source=c.source, members=c.ids, outcome=outcome)
    return {"source": c.source, "members": c.ids,
            "outcome": {**rec.outcome, "spec_hash": spec.hash, "cached": cached}}


def _stands(t: dict[str, Any]) -> bool:
    o = t["outcome"]
    return (o.get("status") == "done" and not o.get("fell")
            and o.get("task_success") is not False)


def _good(t: dict[str, Any], predicted: float) -> bool:
    return _stands(t) and t["outcome"]["objective"] <= predicted * (1.0 + WEAK_MARGIN)


def _rank(t: dict[str, Any]) -> tuple[int, float]:
    o = t["outcome"]
    obj = o.get("objective")
    return (0 if _stands(t) else 1, math.inf if obj is None else float(obj))


def _verdict(t: dict[str, Any], predicted: float) -> str:
    o = t["outcome"]
    if o.get("status") != "done":
        return "failed"
    if o.get("fell"):
        return "falls"
    if o.get("task_success") is False:
        return "fails_task"
    return "good" if _good(t, predicted) else "weak"


def _best_cached(repo: Repository, spec: CanonicalSpec,
                 cands: list[_Candidate]) -> _Candidate | None:
    """The best standing candidate the library kept an outcome of at `spec` (a refinement
    starts there), None when none is kept."""
    best: tuple[float, _Candidate] | None = None
    for c in cands:
        params = [float(v) for v in encode(spec.spec, c.spline)]
        rec = repo.get_verification(spec.hash, _params_hash(params))
        if rec is None or not _stands({"outcome": rec.outcome}):
            continue
        if best is None or rec.outcome["objective"] < best[0]:
            best = (float(rec.outcome["objective"]), c)
    return None if best is None else best[1]


def _message(why: str, verdict: str, predicted: float, best: dict[str, Any],
             tried: list[dict[str, Any]], key: str, value: float) -> str:
    o = best["outcome"]
    if verdict == "good":
        head = (f"{why}; simulated at {key} = {value:g}: stands"
                + ("" if o.get("task_success") is None else " and does its task")
                + f", objective {o['objective']:.4g}")
        if best is not tried[0]:
            head += (f" (the first answer {_what_went_wrong(tried[0])}: the "
                     f"{best['source']} answer of {', '.join(best['members'])} is served "
                     "instead, simulated)")
        return head
    if verdict == "weak":
        return (f"{why}; the best the library holds at {key} = {value:g} stands, objective "
                f"{o['objective']:.4g}, but is more than {WEAK_MARGIN:.0%} above the library's "
                f"prediction {predicted:.4g}: refine it (POST /refinements)")
    return (f"NOT A GOOD ANSWER: no CMRT the library holds stands at {key} = {value:g} "
            f"({'; '.join(t['source'] + ' ' + _what_went_wrong(t) for t in tried)}); "
            "refine it (POST /refinements) or optimise a job there")


def _what_went_wrong(t: dict[str, Any]) -> str:
    o = t["outcome"]
    if o.get("status") != "done":
        return f"failed to simulate ({o.get('error')})"
    if o.get("fell"):
        return f"falls {o.get('fall_direction') or ''}".rstrip()
    if o.get("task_success") is False:
        return "fails its task"
    return f"is weak (objective {o['objective']:.4g})"


__all__ = ["REFINE_MAX_EVALUATIONS", "SOURCES", "SWITCH_DISTANCE", "WEAK_MARGIN", "AnswerError",
           "Answer", "LibraryQuery", "Refine", "Refinement", "Simulate",
           "library_parameter", "refine", "robust_cover", "serve"]
