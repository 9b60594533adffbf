"""What interpolation (`optim.interpolate`) and PCA (`optim.pca`) read of a learned CMRT: an
optimisation's result (`optim.result.OptimizationResult`) and a library entry
(`application.library.LibraryCmrt`) both provide it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol


class CmrtSample(Protocol):
    """A learned CMRT: its name (result name or library id), family, parameter vector and
    spline (knot times, values, vertical values or None, over a clip of `length` s), its
    objective, the clip's task `duration` (s), the `cmrt` block of its spec (how the params
    decode) and its task parameters (`TaskSpec.task_parameters()`)."""

    @property
    def name(self) -> str: ...
    @property
    def family(self) -> str: ...
    @property
    def params(self) -> Sequence[float]: ...
    @property
    def dimension(self) -> int: ...
    @property
    def length(self) -> float: ...
    @property
    def knot_times(self) -> Sequence[float]: ...
    @property
    def values(self) -> Sequence[float]: ...
    @property
    def vertical_values(self) -> Sequence[float] | None: ...
    @property
    def objective(self) -> float: ...
    @property
    def duration(self) -> float: ...
    @property
    def cmrt(self) -> Mapping[str, Any]: ...

    def task_parameters(self) -> dict[str, float]: ...


__all__ = ["CmrtSample"]
