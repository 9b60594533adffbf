"""The library of learned CMRTs: interpolation between its entries and where a new job starts
from it (store + optim glue; no HTTP here). A library entry reaches `optim.interpolate` and
`optim.pca` as a `LibraryCmrt` (the `optim.sample.CmrtSample` they read), built from the stored
record without parsing its spec."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from application.errors import InvalidRequest
from optim.errors import InterpolationError, ParamsError
from optim.family.checks import parameter_distance
from optim.family.spec import SWITCH_DISTANCE
from optim.interpolate import InterpolatedCmrt, bracket, interpolate
from optim.spline import CmrtSpline, decode, encode, sample_curve
from sim.spec import TaskSpec, parse_spec
from store import CmrtEntry, CmrtKey, CmrtRecord, JobStart, Repository

#: Largest number of library CMRTs read for one interpolation or basis.
MAX_MEMBERS = 10_000



def nearer(recs: list[CmrtRecord], key: str, value: float) -> CmrtRecord:
    """The library CMRT nearest `value` along `key` (on a tie, the lower objective)."""
    return min(recs, key=lambda r: (abs(r.task_parameters[key] - value), r.objective))


def params_distance(a: CmrtRecord, b: CmrtRecord) -> float:
    """RMS distance of two library CMRTs' spline parameters (box units); inf for two layouts."""
    return parameter_distance(a.params, b.params)


@dataclass(frozen=True)
class LibraryCmrt:
    """A library CMRT as `optim.interpolate` and `optim.pca` read it (`optim.sample.CmrtSample`):
    named by its library id, its spline, objective and the stored task parameters."""

    name: str
    family: str
    params: list[float]
    length: float
    knot_times: list[float]
    values: list[float]
    vertical_values: list[float] | None
    objective: float
    duration: float
    cmrt: dict[str, Any] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)

    @property
    def dimension(self) -> int:
        return len(self.params)

    def spline(self) -> CmrtSpline:
        """The decoded spline."""
        return CmrtSpline(self.length, self.knot_times, self.values, self.vertical_values)

    def task_parameters(self) -> dict[str, float]:
        return dict(self.parameters)

    @classmethod
    def of(cls, rec: CmrtRecord) -> LibraryCmrt:
        if rec.spec is None:
            raise InterpolationError(f"CMRT {rec.id} has no stored spec")
        values, vertical = rec.values, None
        if values and isinstance(values[0], list | tuple):
            vertical = [float(v[1]) for v in values]
            values = [v[0] for v in values]
        return cls(
            name=rec.id, family=rec.family, params=[float(v) for v in rec.params],
            length=rec.preparation + rec.duration + rec.decay,
            knot_times=[float(v) for v in rec.knots], values=[float(v) for v in values],
            vertical_values=vertical, objective=float(rec.objective),
            duration=float(rec.duration), cmrt=dict(rec.spec.get("cmrt") or {}),
            parameters={k: float(v) for k, v in rec.task_parameters.items()},
        )


def library_entry(spec: TaskSpec, params: Any, *, objective: float, fell: bool,
                  objective_without: float | None = None, fell_without: bool | None = None,
                  winner: str = "search", job_id: str | None = None,
                  spec_document: Mapping[str, Any] | None = None) -> CmrtEntry:
    """The library entry of CMRT `params` optimised for `spec` (its task parameters, decoded
    spline and sampled curve, the spec it was optimised on)."""
    spline = decode(spec, params)
    values: list[Any] = [float(v) for v in spline.values]
    if spline.vertical_values is not None:
        values = [[float(a), float(b)]
                  for a, b in zip(spline.values, spline.vertical_values, strict=True)]
    return CmrtEntry(
        family=spec.family_name, character=spec.character.identity(),
        task_parameters=spec.task_parameters(), preparation=spec.clip.preparation,
        duration=spec.clip.duration, decay=spec.clip.decay,
        params=[float(v) for v in params], knots=[float(v) for v in spline.knot_times],
        values=values, curve=sample_curve(spline), objective=float(objective),
        objective_without=objective_without, fell=bool(fell), fell_without=fell_without,
        winner=winner, job_id=job_id,
        spec=dict(spec_document) if spec_document is not None
        else spec.model_dump(mode="json"),
    )  # fmt: skip


def import_family(repo: Repository, report: Mapping[str, Any]) -> list[str]:
    """Add every member of a family's report (`cmrt family run --out`'s document) to the
    library, each with the spec it was optimised on; returns their library ids."""
    request = report["spec"]  # the family's request: its base spec and the varied parameter
    base = parse_spec(request.get("spec", request), "family spec")
    key = base.library_key(str(report["param"]))
    ids = []
    for m in sorted(report["members"], key=lambda m: m["value"]):
        spec = parse_spec(base.with_parameter(key, float(m["value"])),
                          f"member {m['value']:g}")
        ids.append(repo.add_cmrt(library_entry(
            spec, m["params"], objective=m["objective"], fell=m["fell"],
            objective_without=m.get("baseline_objective"),
            fell_without=m.get("baseline_fell"))))
    return ids


def library_members(repo: Repository, family: str) -> list[LibraryCmrt]:
    """Every library CMRT of `family` that has its spec (at most MAX_MEMBERS), newest first."""
    items, _ = repo.list_cmrts(family, limit=MAX_MEMBERS)
    return [LibraryCmrt.of(r) for r in items if r.spec is not None]


def find_cmrts(repo: Repository, family: str | None, params: Mapping[str, float], *,
               tolerance: float | None, limit: int, offset: int, curves: bool
               ) -> tuple[list[Any], int]:
    """A page of the library's CMRTs (`limit` from `offset`) and how many there are: those of
    `family` (or all) newest first; with task parameters `params`, those at them (nearest
    first within +-`tolerance`), as records when `curves` is asked for, else as keys."""
    if not params:
        return repo.list_cmrts(family, limit=limit, offset=offset)
    if family is None:
        raise InvalidRequest("family: required when querying by task parameters")
    find = repo.find_cmrts if curves else repo.find_cmrt_keys  # keys: no JSON read
    try:
        found = find(family, params, tolerance=tolerance)
    except ValueError as err:
        raise InvalidRequest(str(err)) from None
    return found[offset:offset + limit], len(found)


def interpolated_at(
    repo: Repository,
    family: str,
    key: str,
    value: float,
    *,
    filters: Mapping[str, float] | None = None,
    extrapolate: bool = False,
    like: Callable[[CmrtKey], bool] | None = None,
) -> tuple[InterpolatedCmrt, list[CmrtRecord]]:
    """The CMRT of `family` interpolated at task parameter `key` = `value` among the library
    CMRTs (optionally only those whose other task parameters equal `filters`, and those `like`
    accepts), and the neighbouring library CMRTs it was built from (lower first; one when the
    value is a member's)."""
    keys = [k for k in repo.cmrt_keys(family)[:MAX_MEMBERS] if k.has_spec]
    if like is not None:
        keys = [k for k in keys if like(k)]
    if filters:
        keys = [
            k for k in keys
            if all(abs(k.task_parameters.get(n, np.nan) - v) <= 1e-9 * max(1.0, abs(v))
                   for n, v in filters.items())
        ]
    keys = [k for k in keys if key in k.task_parameters]
    if not keys:
        raise InterpolationError(f"no library CMRTs of family {family!r} with parameter {key!r}")
    members = [repo.get_cmrt(cid) for cid in _neighbour_ids(keys, key, float(value))]
    by_id = {r.id: r for r in members}
    out = interpolate([LibraryCmrt.of(r) for r in members], value, key=key,
                      extrapolate=extrapolate)
    return out, [by_id[cid] for cid in dict.fromkeys((out.lower, out.upper))]


#: CMA-ES step (box units) of a job started from the library: the continuation members' warm
#: sigma (optim.family.spec.WarmConfig), small enough to stay on the neighbours' branch of optima.
LIBRARY_WARM_SIGMA0 = 0.05


def library_start(repo: Repository, spec: TaskSpec) -> JobStart | None:
    """Where a new job of `spec` starts when the library knows its neighbourhood: the CMRT
    interpolated along one task parameter between library CMRTs of the spec's family on
    either side (the others equal), or the stored CMRT at exactly these parameters, encoded
    for this spec; None when there is none (the job starts from the flat spline). The start
    records what it came from and the small step it is searched with."""
    params = spec.task_parameters()
    family = spec.family_name
    character = spec.character.identity()

    def like(k: CmrtKey) -> bool:  # the same clip around the task window, the same character
        return (abs(k.preparation - spec.clip.preparation) <= 1e-9
                and abs(k.decay - spec.clip.decay) <= 1e-9 and k.character == character
                and k.knots == spec.cmrt.knots and k.vertical == spec.cmrt.vertical)

    for key in sorted(params):
        filters = {k: v for k, v in params.items() if k != key}
        try:
            out, recs = interpolated_at(repo, family, key, params[key], filters=filters,
                                        like=like)
        except InterpolationError:
            continue
        spline = out.spline()
        ids = [r.id for r in recs]
        what = (f"library CMRT {ids[0]} ({key} = {params[key]:g})" if out.exact else
                f"library: interpolated along {key} between {out.lower_value:g} and "
                f"{out.upper_value:g} (weight {out.weight:.3f})")
        if not out.exact and len(ids) == 2:  # across a strategy switch: never the average
            a, b = recs
            distance = params_distance(a, b)
            if distance > SWITCH_DISTANCE:
                near = nearer(recs, key, params[key])
                spline = LibraryCmrt.of(near).spline()
                ids = [near.id]
                what = (f"library CMRT {near.id} ({key} = {near.task_parameters[key]:g}), the "
                        f"nearer neighbour: a strategy switch lies between the neighbours "
                        f"(parameters {distance:.2f} apart)")
        try:
            x0 = encode(spec, spline)
        except ParamsError:  # another spline layout: not a start for this spec
            continue
        return JobStart(what, tuple(float(v) for v in x0), LIBRARY_WARM_SIGMA0, tuple(ids))
    return None


def _neighbour_ids(keys: list[CmrtKey], key: str, value: float) -> list[str]:
    """The library CMRTs `optim.interpolate.interpolate` would read among `keys` (ordered as
    stored, newest first), so that only those are loaded with their specs and curves: at each
    value of `key` the lowest objective (the first on ties, as `interpolate` keeps it), then
    the sample itself or the two around `value` (at an end: the two nearest). The whole
    family's spline layouts must agree, as `interpolate` requires of what it is given."""
    first = keys[0]
    for k in keys:
        if (k.knots, k.vertical) != (first.knots, first.vertical):
            raise InterpolationError(
                f"result {k.id!r} has a different spline layout than {first.id!r}")
    best: dict[float, CmrtKey] = {}
    for k in keys:
        v = k.task_parameters[key]
        if v not in best or k.objective < best[v].objective:
            best[v] = k
    xs = sorted(best)
    if len(xs) < 2 or not np.isfinite(value):
        return [k.id for k in keys]  # `interpolate` gives the reason
    if value in best:
        other = xs[1] if xs[0] == value else xs[0]
        return [best[value].id, best[other].id]
    a, b = bracket(xs, value)
    return [best[a].id, best[b].id]


__all__ = ["LIBRARY_WARM_SIGMA0", "MAX_MEMBERS", "SWITCH_DISTANCE", "LibraryCmrt",
           "find_cmrts", "import_family", "library_entry", "library_members",
           "interpolated_at", "library_start", "nearer", "params_distance"]
