"""The CMRT spline (paper section 4): a piecewise cubic through a few control points.

A CMRT is the displacement (metres) of the centre-of-mass reference from the support centre as
a function of clip time t (seconds from the clip start). It is a clamped cubic interpolating
spline (C2) through the nodes

    (0, 0), (t_1, v_1), ..., (t_n, v_n), (L, 0)        L = spec.clip.length

with zero slope at t = 0 and at t = L, so it starts and ends with no displacement and no
velocity. Outside [0, L] the displacement is exactly 0. With `spec.cmrt.vertical` a second
spline with the same knot times gives the vertical displacement.

Parameter vector (what CMA-ES searches), all entries in [0, 1], length d = spec.cmrt_dimension:

    p[0:n]      knot times     n = spec.cmrt.knots
    p[n:2n]     horizontal values
    p[2n:3n]    vertical values (only if spec.cmrt.vertical)

Decoding rules:
  * values: v = (2 p - 1) * max_displacement (max_vertical for the vertical ones), so
    p = 0.5 -> exactly 0 m, p = 0 -> -max, p = 1 -> +max. The curve between knots may overshoot
    the control values (it is a cubic), it is not clipped.
  * knot times ("own sub-interval" rule): the clip [0, L] is cut into n equal sub-intervals of
    width w = L / n; knot i (0-based) lives in its own sub-interval, shrunk by g / 2 at each
    side, where g = min(MIN_KNOT_GAP_S, w / 2) is the minimum gap:
        t_i = i w + g / 2 + p_i (w - g)
    Hence for every p in [0, 1]^n the knots are strictly increasing, consecutive knots are at
    least g apart and every knot is at least g / 2 inside (0, L). p_i = 0.5 puts knot i at the
    middle of its sub-interval: equally spaced knots (spacing w).
  * parameters outside [0, 1] are clipped into it (CMA-ES with bounds never produces them);
    NaN or a wrong length raises `ParamsError`.

`flat_params(spec)` (all 0.5) is the flat spline: equally spaced knots, zero values, and it
evaluates to exactly 0.0 everywhere (the no-anticipation baseline and the default CMA start).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from optim.errors import ParamsError
from sim.linalg import solve

if TYPE_CHECKING:
    from sim.spec import CmrtConfig, TaskSpec

#: Largest minimum spacing between consecutive knots, seconds (shrunk to w/2 for short clips).
MIN_KNOT_GAP_S = 0.05
#: Number of samples of the curve stored in results (`sample_curve`).
CURVE_SAMPLES = 100


# ---------------------------------------------------------------------------------------------
# clamped cubic spline
# ---------------------------------------------------------------------------------------------
def clamped_cubic_coefficients(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficients of the C2 cubic spline through (x, y) with zero slope at both ends.

    x: strictly increasing node abscissae (m + 1 >= 2 of them); y: node values.
    Returns an (m, 4) array: on [x_j, x_{j+1}], S(t) = a + b s + c s^2 + d s^3 with s = t - x_j.
    All-zero y gives exactly all-zero coefficients.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    h = np.diff(x)
    if x.ndim != 1 or x.shape != y.shape or len(x) < 2 or np.any(h <= 0):
        raise ParamsError("spline nodes must be strictly increasing with matching values")
    m = len(h)
    slope = np.diff(y) / h
    # Unknowns: second derivatives M_0..M_m at the nodes (clamped end conditions S' = 0).
    A = np.zeros((m + 1, m + 1))
    r = np.zeros(m + 1)
    A[0, 0], A[0, 1] = 2.0 * h[0], h[0]
    r[0] = 6.0 * slope[0]
    for j in range(1, m):
        A[j, j - 1], A[j, j], A[j, j + 1] = h[j - 1], 2.0 * (h[j - 1] + h[j]), h[j]
        r[j] = 6.0 * (slope[j] - slope[j - 1])
    A[m, m - 1], A[m, m] = h[m - 1], 2.0 * h[m - 1]
    r[m] = -6.0 * slope[m - 1]
    M = solve(A, r)
    coef = np.empty((m, 4))
    coef[:, 0] = y[:-1]
    coef[:, 1] = slope - h * (2.0 * M[:-1] + M[1:]) / 6.0
    coef[:, 2] = M[:-1] / 2.0
    coef[:, 3] = (M[1:] - M[:-1]) / (6.0 * h)
    return coef


class _Cubic:
    """One clamped cubic on [0, L]; zero outside. Fast scalar path for the 1 ms sim loop."""

    __slots__ = ("coef", "nodes", "_rows", "_nodes_list", "_length")

    def __init__(self, nodes: np.ndarray, values: np.ndarray) -> None:
        self.nodes = np.asarray(nodes, dtype=float)
        self.coef = clamped_cubic_coefficients(self.nodes, values)
        self._nodes_list = [float(v) for v in self.nodes]
        self._rows = [tuple(float(c) for c in row) for row in self.coef]
        self._length = self._nodes_list[-1]

    def scalar(self, t: float) -> float:
        if not 0.0 < t < self._length:  # also catches NaN
            return 0.0
        j = bisect.bisect_right(self._nodes_list, t) - 1
        a, b, c, d = self._rows[j]
        s = t - self._nodes_list[j]
        return a + s * (b + s * (c + s * d))

    def _locate(self, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        j = np.clip(np.searchsorted(self.nodes, ts, side="right") - 1, 0, len(self.coef) - 1)
        inside = (ts > 0.0) & (ts < self._length)
        return j, ts - self.nodes[j], inside

    def many(self, ts: np.ndarray) -> np.ndarray:
        j, s, inside = self._locate(ts)
        c = self.coef[j]
        out = c[:, 0] + s * (c[:, 1] + s * (c[:, 2] + s * c[:, 3]))
        return np.where(inside, out, 0.0)

    def derivative(self, ts: np.ndarray) -> np.ndarray:
        j, s, inside = self._locate(ts)
        c = self.coef[j]
        out = c[:, 1] + s * (2.0 * c[:, 2] + 3.0 * s * c[:, 3])
        # The one-sided slope at the clip ends is that of the curve (0 by construction).
        at_ends = (ts == 0.0) | (ts == self._length)
        return np.where(inside | at_ends, out, 0.0)


# ---------------------------------------------------------------------------------------------
# the CMRT spline object
# ---------------------------------------------------------------------------------------------
class CmrtSpline:
    """A CMRT: `spline(t)` is the displacement in metres at clip time t (seconds).

    `knot_times` (s, strictly increasing inside (0, length)), `values` (m, horizontal) and
    optionally `vertical_values` (m). Calling returns a float, or a `(dx, dy)` tuple when the
    spline has vertical values; `sample(ts)` is the vectorised form ((m,) or (m, 2) array).
    Zero (and zero slope) at t = 0 and t = length, zero outside [0, length]. Picklable.
    """

    def __init__(
        self,
        length: float,
        knot_times: Sequence[float] | np.ndarray,
        values: Sequence[float] | np.ndarray,
        vertical_values: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        L = float(length)
        kt = np.asarray(knot_times, dtype=float).reshape(-1)
        vx = np.asarray(values, dtype=float).reshape(-1)
        if not (math.isfinite(L) and L > 0.0):
            raise ParamsError(f"spline length must be a positive number of seconds, got {length!r}")
        if len(kt) < 1:
            raise ParamsError("spline needs at least one knot")
        if len(vx) != len(kt):
            raise ParamsError(f"spline has {len(kt)} knot times but {len(vx)} values")
        if not (np.all(np.isfinite(kt)) and np.all(np.isfinite(vx))):
            raise ParamsError("spline knot times and values must be finite")
        if np.any(np.diff(kt) <= 0.0) or kt[0] <= 0.0 or kt[-1] >= L:
            raise ParamsError(
                f"spline knot times must be strictly increasing inside (0, {L:g}) s, "
                f"got {[round(float(v), 6) for v in kt]}"
            )
        vy = None
        if vertical_values is not None:
            vy = np.asarray(vertical_values, dtype=float).reshape(-1)
            if len(vy) != len(kt) or not np.all(np.isfinite(vy)):
                raise ParamsError(
                    f"spline has {len(kt)} knot times but {len(vy)} vertical values"
                    if len(vy) != len(kt)
                    else "spline vertical values must be finite"
                )
        self.length = L
        self.knot_times = kt
        self.values = vx
        self.vertical_values = vy
        nodes = np.concatenate(([0.0], kt, [L]))
        self._x = _Cubic(nodes, np.concatenate(([0.0], vx, [0.0])))
        self._y = None if vy is None else _Cubic(nodes, np.concatenate(([0.0], vy, [0.0])))

    # -- evaluation -------------------------------------------------------------------------
    @property
    def vertical(self) -> bool:
        """True when the spline also carries a vertical displacement."""
        return self._y is not None

    def __call__(self, t: float) -> float | tuple[float, float]:
        """Displacement at clip time t (s): metres, or (dx, dy) metres when vertical."""
        t = float(t)
        if self._y is None:
            return self._x.scalar(t)
        return (self._x.scalar(t), self._y.scalar(t))

    def sample(self, ts: Sequence[float] | np.ndarray) -> np.ndarray:
        """Vectorised evaluation: shape (m,) horizontal, or (m, 2) [dx, dy] when vertical."""
        arr = np.asarray(ts, dtype=float).reshape(-1)
        dx = self._x.many(arr)
        if self._y is None:
            return dx
        return np.column_stack([dx, self._y.many(arr)])

    def derivative(self, ts: Sequence[float] | np.ndarray, component: int = 0) -> np.ndarray:
        """d(displacement)/dt in m/s at `ts` (component 0 horizontal, 1 vertical)."""
        arr = np.asarray(ts, dtype=float).reshape(-1)
        cubic = self._x if component == 0 else self._y
        if cubic is None:
            raise ParamsError("this spline has no vertical component")
        return cubic.derivative(arr)

    # -- serialisation ----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: {"length", "knot_times", "values"[, "vertical_values"]} (s and m)."""
        d: dict[str, Any] = {
            "length": self.length,
            "knot_times": [float(v) for v in self.knot_times],
            "values": [float(v) for v in self.values],
        }
        if self.vertical_values is not None:
            d["vertical_values"] = [float(v) for v in self.vertical_values]
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CmrtSpline:
        """Inverse of `to_dict`; a missing or bad field raises `ParamsError` naming it."""
        if not isinstance(data, Mapping):
            raise ParamsError("spline: expected a mapping")
        for key in ("length", "knot_times", "values"):
            if key not in data:
                raise ParamsError(f"spline: missing field {key!r}")
        try:
            return cls(
                data["length"], data["knot_times"], data["values"], data.get("vertical_values")
            )
        except (TypeError, ValueError) as err:
            if isinstance(err, ParamsError):
                raise
            raise ParamsError(f"spline: bad field value ({err})") from None

    def __getstate__(self) -> dict[str, Any]:
        return self.to_dict()

    def __setstate__(self, state: dict[str, Any]) -> None:
        other = CmrtSpline.from_dict(state)
        self.__dict__.update(other.__dict__)

    def __repr__(self) -> str:
        kt = ", ".join(f"{v:.3f}" for v in self.knot_times)
        vx = ", ".join(f"{v:+.4f}" for v in self.values)
        extra = "" if self.vertical_values is None else ", vertical"
        return f"CmrtSpline(length={self.length:g}, knots=[{kt}], values=[{vx}]{extra})"

    @classmethod
    def zero(cls, length: float, knots: int = 4) -> CmrtSpline:
        """The flat spline of a clip: equally spaced knots (sub-interval midpoints), zero values."""
        w = float(length) / knots
        return cls(length, (np.arange(knots) + 0.5) * w, np.zeros(knots))


# ---------------------------------------------------------------------------------------------
# parameter encoding
# ---------------------------------------------------------------------------------------------
def min_knot_gap(length: float, knots: int) -> float:
    """The minimum gap g (s) between consecutive knots for a clip of `length` s."""
    return min(MIN_KNOT_GAP_S, 0.5 * float(length) / knots)


def knot_time_bounds(length: float, knots: int) -> tuple[np.ndarray, np.ndarray]:
    """(lowest, highest) time (s) of each knot: its own sub-interval shrunk by g/2 at each side."""
    w = float(length) / knots
    g = min_knot_gap(length, knots)
    lo = np.arange(knots) * w + 0.5 * g
    return lo, lo + (w - g)


def check_params(spec: TaskSpec, params: Sequence[float] | np.ndarray) -> np.ndarray:
    """`params` as a float array of length spec.cmrt_dimension, clipped into [0, 1].

    Raises ParamsError for a wrong length or non-finite entries.
    """
    p = np.asarray(params, dtype=float).reshape(-1)
    d = spec.cmrt_dimension
    if len(p) != d:
        raise ParamsError(
            f"params: expected {d} numbers for spec {spec.name!r} "
            f"({spec.cmrt.knots} knots{', vertical' if spec.cmrt.vertical else ''}), got {len(p)}"
        )
    if not np.all(np.isfinite(p)):
        raise ParamsError("params: every entry must be a finite number")
    return np.clip(p, 0.0, 1.0)


def decode_params(
    params: Sequence[float] | np.ndarray, *, length: float, config: CmrtConfig
) -> CmrtSpline:
    """Decode a parameter vector for a clip of `length` s and a CmrtConfig (see module doc)."""
    n = config.knots
    per = 3 if config.vertical else 2
    p = np.asarray(params, dtype=float).reshape(-1)
    if len(p) != per * n:
        raise ParamsError(f"params: expected {per * n} numbers, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise ParamsError("params: every entry must be a finite number")
    p = np.clip(p, 0.0, 1.0)
    lo, hi = knot_time_bounds(length, n)
    times = lo + p[:n] * (hi - lo)
    vx = (2.0 * p[n : 2 * n] - 1.0) * config.max_displacement
    vy = (2.0 * p[2 * n : 3 * n] - 1.0) * config.max_vertical if config.vertical else None
    return CmrtSpline(length, times, vx, vy)


def decode(spec: TaskSpec, params: Sequence[float] | np.ndarray) -> CmrtSpline:
    """The CmrtSpline of `params` for `spec` (clip length and spec.cmrt)."""
    return decode_params(check_params(spec, params), length=spec.clip.length, config=spec.cmrt)


def encode(spec: TaskSpec, spline: CmrtSpline, *, clip: bool = True) -> np.ndarray:
    """Parameter vector of `spline` for `spec` (inverse of `decode`).

    Knot times outside their sub-interval and values beyond the maximum displacement are
    clipped into [0, 1] (clip=False returns the raw, possibly out-of-range encoding).
    A spline without vertical values encodes them as 0.5 (no displacement) for a vertical spec.
    """
    cfg = spec.cmrt
    n = cfg.knots
    if len(spline.knot_times) != n:
        raise ParamsError(
            f"spline has {len(spline.knot_times)} knots but spec {spec.name!r} uses {n}"
        )
    lo, hi = knot_time_bounds(spec.clip.length, n)
    parts = [
        (spline.knot_times - lo) / (hi - lo),
        (spline.values / cfg.max_displacement + 1.0) / 2.0,
    ]
    if cfg.vertical:
        vy = spline.vertical_values if spline.vertical_values is not None else np.zeros(n)
        parts.append((vy / cfg.max_vertical + 1.0) / 2.0)
    p = np.concatenate(parts)
    return np.clip(p, 0.0, 1.0) if clip else p


def flat_params(spec: TaskSpec) -> np.ndarray:
    """The flat spline's parameters (all 0.5): equally spaced knots, zero displacement."""
    return np.full(spec.cmrt_dimension, 0.5)


def sample_curve(spline: CmrtSpline, samples: int = CURVE_SAMPLES) -> dict[str, list[float]]:
    """`samples` equally spaced points over [0, length]: {"t": s, "dx": m[, "dy": m]}."""
    ts = np.linspace(0.0, spline.length, samples)
    ys = spline.sample(ts)
    out = {"t": [float(v) for v in ts]}
    if ys.ndim == 1:
        out["dx"] = [float(v) for v in ys]
    else:
        out["dx"] = [float(v) for v in ys[:, 0]]
        out["dy"] = [float(v) for v in ys[:, 1]]
    return out


__all__ = [
    "CURVE_SAMPLES",
    "MIN_KNOT_GAP_S",
    "CmrtSpline",
    "check_params",
    "clamped_cubic_coefficients",
    "decode",
    "decode_params",
    "encode",
    "flat_params",
    "knot_time_bounds",
    "min_knot_gap",
    "sample_curve",
]
