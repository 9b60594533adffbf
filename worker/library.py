"""Library operations on stored CMRTs: interpolation and PCA bases (store + optim glue, used
by the API; no HTTP here)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from optim.errors import BasisError, InterpolationError, ParamsError
from optim.interpolate import bracket, interpolate
from optim.pca import DEFAULT_K, Basis, build_basis
from optim.result import OptimizationResult
from optim.spline import CmrtSpline, encode, sample_curve
from sim.spec import TaskSpec
from store import CmrtKey, CmrtRecord, Repository

#: Largest number of library CMRTs read for one interpolation or basis.
MAX_MEMBERS = 10_000


def record_to_result(rec: CmrtRecord) -> OptimizationResult:
    """An OptimizationResult view of a library CMRT (for optim.interpolate / optim.pca)."""
    if rec.spec is None:
        raise InterpolationError(f"CMRT {rec.id} has no stored spec")
    values = rec.values
    vertical = None
    if values and isinstance(values[0], list | tuple):
        vertical = [float(v[1]) for v in values]
        values = [float(v[0]) for v in values]
    spec = dict(rec.spec)
    spec["name"] = rec.id  # results are named by their library id in the answers
    spec["family"] = rec.family
    return OptimizationResult(
        spec=spec,
        dimension=len(rec.params),
        params=[float(v) for v in rec.params],
        length=rec.preparation + rec.duration + rec.decay,
        knot_times=[float(v) for v in rec.knots],
        values=[float(v) for v in values],
        vertical_values=vertical,
        curve=rec.curve,
        objective=rec.objective,
        fell=rec.fell,
        baseline_objective=rec.objective_without if rec.objective_without is not None
        else rec.objective,
        baseline_fell=bool(rec.fell_without),
        evaluations=0,
        iterations=0,
        stop_rule="library",
        wall_seconds=0.0,
        seed=0,
    )


def _family(repo: Repository, family: str) -> list[CmrtRecord]:
    items, _ = repo.list_cmrts(family, limit=MAX_MEMBERS)
    return [r for r in items if r.spec is not None]


def interpolate_library(
    repo: Repository,
    family: str,
    key: str,
    value: float,
    *,
    filters: Mapping[str, float] | None = None,
    extrapolate: bool = False,
    like: Callable[[CmrtKey], bool] | None = None,
) -> dict[str, Any]:
    """Interpolated CMRT of `family` at task parameter `key` = `value` among the library CMRTs
    (optionally only those whose other task parameters equal `filters`, and those `like`
    accepts)."""
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
    out = interpolate([record_to_result(r) for r in members], value, key=key,
                      extrapolate=extrapolate)
    spline = out.spline()
    d = out.to_dict()
    neighbours = []
    for cid, v in ((out.lower, out.lower_value), (out.upper, out.upper_value)):
        if neighbours and neighbours[0]["id"] == cid:
            continue
        r = by_id[cid]
        neighbours.append({"id": cid, key: v, "objective": r.objective,
                           "task_parameters": r.task_parameters})
    return {
        "family": family,
        "key": key,
        "value": value,
        "weight": d["weight"],
        "exact": d["exact"],
        "extrapolated": d["extrapolated"],
        "neighbours": neighbours,
        "length": d["length"],
        "knot_times": d["knot_times"],
        "values": d["values"],
        "vertical_values": d["vertical_values"],
        "curve": sample_curve(spline),
    }


#: CMA-ES step (box units) of a job started from the library: the continuation members' warm
#: sigma (optim.family.WarmConfig), small enough to stay on the neighbours' branch of optima.
LIBRARY_WARM_SIGMA0 = 0.05


def library_start(repo: Repository, spec: TaskSpec) -> dict[str, Any] | None:
    """Where a new job of `spec` starts when the library knows its neighbourhood: the CMRT
    interpolated along one task parameter between library CMRTs of the spec's family on
    either side (the others equal), or the stored CMRT at exactly these parameters, encoded
    for this spec; None when there is none (the job starts from the flat spline). The start
    records what it came from and the small step it is searched with."""
    params = spec.task_parameters()
    family = spec.family_name
    character = spec.character.model_dump(mode="json")

    def like(k: CmrtKey) -> bool:  # the same clip around the task window, the same character
        return (abs(k.preparation - spec.clip.preparation) <= 1e-9
                and abs(k.decay - spec.clip.decay) <= 1e-9 and k.character == character
                and k.knots == spec.cmrt.knots and k.vertical == spec.cmrt.vertical)

    for key in sorted(params):
        filters = {k: v for k, v in params.items() if k != key}
        try:
            out = interpolate_library(repo, family, key, params[key], filters=filters,
                                      like=like)
        except InterpolationError:
            continue
        vy = out["vertical_values"]
        spline = CmrtSpline(out["length"], np.asarray(out["knot_times"]),
                            np.asarray(out["values"]),
                            None if vy is None else np.asarray(vy))
        try:
            x0 = encode(spec, spline)
        except ParamsError:  # another spline layout: not a start for this spec
            continue
        ids = [n["id"] for n in out["neighbours"]]
        what = (f"library CMRT {ids[0]} ({key} = {params[key]:g})" if out["exact"] else
                f"library: interpolated along {key} between " + " and ".join(
                    f"{n[key]:g}" for n in out["neighbours"]) + f" (weight {out['weight']:.3f})")
        return {"from": what, "x0": [float(v) for v in x0], "sigma0": LIBRARY_WARM_SIGMA0,
                "cmrts": ids}
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


def build_library_basis(repo: Repository, family: str, k: int = DEFAULT_K) -> str:
    """PCA basis of every library CMRT of `family`; stored, returns its id."""
    members = _family(repo, family)
    if not members:
        raise BasisError(f"no library CMRTs of family {family!r}")
    basis = build_basis([record_to_result(r) for r in members], k=k, family=family)
    return store_basis(repo, basis, family, [r.id for r in members])


def store_basis(repo: Repository, basis: Basis, family: str, members: list[str]) -> str:
    """Keep a PCA basis in the store (`basis_from_record` reads it back); returns its id."""
    return repo.add_basis(
        family=family,
        k=basis.k,
        mean=[float(v) for v in basis.mean],
        components=[[float(v) for v in row] for row in basis.components],
        variance_explained=[float(v) for v in basis.variance_explained],
        members=members,
        box={
            "score_lo": [float(v) for v in basis.score_lo],
            "score_hi": [float(v) for v in basis.score_hi],
            "margin": basis.margin,
            "cmrt": basis.cmrt,
            "content_id": basis.id,
        },
    )
