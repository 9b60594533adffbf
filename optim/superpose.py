"""Superposition of time-shifted CMRTs (paper section 4.2).

For parts [(s_1, c_1), ..., (s_m, c_m)] (start offset s_i in seconds of the composite clip,
c_i a CMRT of its own clip, e.g. a `CmrtSpline`), the composite is

    CMRT(t) = sum_i c_i(t - s_i)

Each spline is zero outside its own [0, length], so a part contributes only during
[s_i, s_i + length_i]; overlapping parts add. If any part returns (dx, dy) the composite
returns (dx, dy) tuples, horizontal-only parts contributing dy = 0. The object is a valid sim
CMRT (any callable t -> float | (dx, dy)) and is picklable when its parts are.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from optim.spline import CmrtSpline

CmrtCallable = Callable[[float], "float | tuple[float, float]"]


def _is_vertical(part: Any) -> bool:
    if isinstance(part, CmrtSpline):
        return part.vertical
    return isinstance(part(0.0), tuple)


class Superposition:
    """CMRT(t) = sum_i part_i(t - offset_i); see module docstring."""

    def __init__(self, parts: Sequence[tuple[float, CmrtCallable]]) -> None:
        self.parts: list[tuple[float, CmrtCallable]] = [(float(s), c) for s, c in parts]
        self.vertical = any(_is_vertical(c) for _, c in self.parts)

    def __call__(self, t: float) -> float | tuple[float, float]:
        t = float(t)
        dx = dy = 0.0
        for s, c in self.parts:
            v = c(t - s)
            if isinstance(v, tuple):
                dx += v[0]
                dy += v[1]
            else:
                dx += v
        return (dx, dy) if self.vertical else dx

    def sample(self, ts: Sequence[float] | np.ndarray) -> np.ndarray:
        """Vectorised: shape (m,) or (m, 2) when vertical."""
        arr = np.asarray(ts, dtype=float).reshape(-1)
        out = np.zeros((len(arr), 2))
        for s, c in self.parts:
            if isinstance(c, CmrtSpline):
                v = c.sample(arr - s)
            else:
                v = np.array([c(t - s) for t in arr], dtype=float)
            if v.ndim == 2:
                out += v
            else:
                out[:, 0] += v
        return out if self.vertical else out[:, 0]

    @property
    def end(self) -> float:
        """Latest time (s) any spline part is non-zero (its offset + length)."""
        ends = [s + c.length for s, c in self.parts if isinstance(c, CmrtSpline)]
        return max(ends, default=0.0)


def superpose(parts: Sequence[tuple[float, CmrtCallable]]) -> Superposition:
    """The composite CMRT of `(start offset s, cmrt)` pairs."""
    return Superposition(parts)


__all__ = ["Superposition", "superpose"]
