"""Interpolation of optimised CMRTs along a task parameter (paper section 4.2).

`interpolate(results, value, key="duration")` takes results of one family, reads each one's
task parameter `key` (TaskSpec.task_parameters(), e.g. "duration" in seconds or "force" in
newtons) and linearly interpolates, between the two results nearest to `value` on either side,
the DECODED spline: knot times (s), control values (m, and vertical values) and the clip
length (s). Interpolating knot times in seconds lets the anticipation shift in time with the
task (the paper's choice: "using the knots values and control points"); for members with the
same clip length and CMRT settings this equals interpolating the params, since the decoding is
affine.

Rules:
  * at least two results with distinct parameter values are needed; several results at the
    same value: the one with the lowest objective is used;
  * a value equal to a sample's returns exactly that sample (`exact=True`);
  * outside the sampled range: InterpolationError unless extrapolate=True, in which case the
    two nearest results at that end are extended linearly and `extrapolated=True`;
    an extrapolation that breaks the knot ordering raises InterpolationError;
  * all results must share the family and the number of knots / vertical setting.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from optim.errors import InterpolationError, ParamsError
from optim.spline import CmrtSpline, encode

if TYPE_CHECKING:
    from optim.sample import CmrtSample
    from sim.spec import TaskSpec


@dataclass(frozen=True)
class InterpolatedCmrt:
    """An interpolated CMRT: decoded spline data plus where it came from.

    weight: position between `lower` (0) and `upper` (1); < 0 or > 1 when extrapolated.
    """

    key: str
    value: float
    length: float  # s
    knot_times: np.ndarray  # s
    values: np.ndarray  # m
    vertical_values: np.ndarray | None  # m
    lower: str
    upper: str
    lower_value: float
    upper_value: float
    weight: float
    extrapolated: bool
    exact: bool

    def spline(self) -> CmrtSpline:
        """The interpolated CMRT as a callable spline."""
        return CmrtSpline(self.length, self.knot_times, self.values, self.vertical_values)

    def params(self, spec: TaskSpec) -> np.ndarray:
        """Parameter vector for `spec` (clipped into [0, 1]; e.g. a warm start for CMA-ES)."""
        return encode(spec, self.spline())

    def to_dict(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "value": self.value,
            "length": self.length,
            "knot_times": [float(v) for v in self.knot_times],
            "values": [float(v) for v in self.values],
            "vertical_values": None
            if self.vertical_values is None
            else [float(v) for v in self.vertical_values],
            "lower": self.lower,
            "upper": self.upper,
            "lower_value": self.lower_value,
            "upper_value": self.upper_value,
            "weight": self.weight,
            "extrapolated": self.extrapolated,
            "exact": self.exact,
        }


def _param_of(result: CmrtSample, key: str) -> float:
    try:
        params = result.task_parameters()
    except Exception as err:  # noqa: BLE001 - a bad spec in a result is a domain error here
        raise InterpolationError(f"result {result.name!r}: cannot read its spec ({err})") from None
    if key not in params:
        raise InterpolationError(
            f"result {result.name!r} has no task parameter {key!r} "
            f"(it has {', '.join(sorted(params))})"
        )
    return float(params[key])


def _arrays(r: CmrtSample) -> tuple[float, np.ndarray, np.ndarray, np.ndarray | None]:
    vy = None if r.vertical_values is None else np.asarray(r.vertical_values, dtype=float)
    return r.length, np.asarray(r.knot_times, float), np.asarray(r.values, float), vy


def bracket(xs: Sequence[float], value: float) -> tuple[float, float]:
    """The two sampled values `value` is interpolated between (sorted, distinct `xs`, at
    least two): its neighbours on either side, or the two nearest at an end of the range."""
    if value < xs[0]:
        return xs[0], xs[1]
    if value > xs[-1]:
        return xs[-2], xs[-1]
    j = int(np.searchsorted(xs, value))
    return xs[j - 1], xs[j]


def interpolate(
    results: Sequence[CmrtSample],
    value: float,
    *,
    key: str = "duration",
    extrapolate: bool = False,
    values: Sequence[float] | None = None,
) -> InterpolatedCmrt:
    """Interpolated CMRT at task parameter `key` = `value` (see module docstring).

    values: each result's parameter value, in order (a family along a spec path that is not
    one of the task's parameters, e.g. `task.width`); default: read `key` from each result's
    task parameters. `key` then only names the parameter in messages and the output."""
    value = float(value)
    if not np.isfinite(value):
        raise InterpolationError(f"{key} must be a finite number, got {value}")
    if len(results) < 2:
        raise InterpolationError(f"interpolation needs at least 2 results, got {len(results)}")
    if values is not None and len(values) != len(results):
        raise InterpolationError(f"{len(values)} parameter values for {len(results)} results")
    best = _best_per_value(results, key, values)
    xs = sorted(best)
    if len(xs) < 2:
        raise InterpolationError(
            f"interpolation needs results at 2 distinct {key} values, got only {xs[0]:g}"
        )

    if value in best:
        r = best[value]
        L, kt, vx, vy = _arrays(r)
        return InterpolatedCmrt(
            key, value, L, kt, vx, vy, r.name, r.name, value, value, 0.0, False, True
        )

    extrapolated = not xs[0] < value < xs[-1]
    if extrapolated and not extrapolate:
        raise InterpolationError(
            f"{key} = {value:g} is outside the sampled range [{xs[0]:g}, {xs[-1]:g}] of family "
            f"{results[0].family!r}; extrapolating past it must be asked for (extrapolate)"
        )
    a, b = bracket(xs, value)
    return _blend(best[a], best[b], a, b, key, value, extrapolated)


def _best_per_value(
    results: Sequence[CmrtSample], key: str, values: Sequence[float] | None
) -> dict[float, CmrtSample]:
    """Parameter value -> the result of lowest objective there; every result must share the
    first one's family and spline layout."""
    fam = results[0].family
    shape = (len(results[0].knot_times), results[0].vertical_values is not None)
    best: dict[float, CmrtSample] = {}
    for i, r in enumerate(results):
        if r.family != fam:
            raise InterpolationError(
                f"results of different families: {results[0].name!r} is {fam!r}, "
                f"{r.name!r} is {r.family!r}"
            )
        if (len(r.knot_times), r.vertical_values is not None) != shape:
            raise InterpolationError(
                f"result {r.name!r} has a different spline layout than {results[0].name!r}"
            )
        v = _param_of(r, key) if values is None else float(values[i])
        if v not in best or r.objective < best[v].objective:
            best[v] = r
    return best


def _blend(
    lower: CmrtSample, upper: CmrtSample, a: float, b: float, key: str, value: float,
    extrapolated: bool,
) -> InterpolatedCmrt:
    """The decoded splines of `lower` (at `a`) and `upper` (at `b`) combined linearly at
    `value`; InterpolationError if the result is not a valid spline."""
    w = (value - a) / (b - a)
    La, kta, vxa, vya = _arrays(lower)
    Lb, ktb, vxb, vyb = _arrays(upper)
    L = (1.0 - w) * La + w * Lb
    kt = (1.0 - w) * kta + w * ktb
    vx = (1.0 - w) * vxa + w * vxb
    vy = None if vya is None or vyb is None else (1.0 - w) * vya + w * vyb
    out = InterpolatedCmrt(
        key,
        value,
        float(L),
        kt,
        vx,
        vy,
        lower.name,
        upper.name,
        a,
        b,
        float(w),
        extrapolated,
        False,
    )
    try:
        out.spline()
    except ParamsError as err:
        raise InterpolationError(
            f"{'extrapolation' if extrapolated else 'interpolation'} to {key} = {value:g} "
            f"gives an invalid spline: {err}"
        ) from None
    return out


__all__ = ["InterpolatedCmrt", "bracket", "interpolate"]
