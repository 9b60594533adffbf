"""What evaluating one candidate is and gives (light module: numpy-free imports):
`Objective`, what every executor evaluates; `CuttableObjective`, the objectives that may stop
early as the certain last of their generation (`optim.rankcut`); `EvalOutcome`, the result.

Kept apart from `optim.executors` and `optim.cmaes` so pool worker processes and objectives
import it without pulling in pycma (which takes ~1.5 s to import).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol

#: Objective recorded for a failed evaluation, and given to CMA-ES in place of NaN / inf.
#: Far above any CP-error norm or fall penalty (metres), so failures rank worst.
FAILED_OBJECTIVE = 1.0e9


@dataclass(frozen=True)
class EvalOutcome:
    """Result of evaluating one candidate.

    objective: value to minimise (m for the CMRT objective; FAILED_OBJECTIVE on error);
    fell: the character fell; cpu_seconds: CPU time of the evaluation (s);
    error: None, or "ExceptionType: message" when the evaluation raised;
    cut: stopped early as the certain last of its generation (`optim.rankcut`): `objective`
    is a lower bound of the candidate's objective; sim_seconds: simulated seconds spent;
    fall_time (s from the clip's start), fall_direction ("forward" | "backward") and
    task_success (the task's own goal: ball held, block toppled, ...): None when they do not
    apply (no fall; a task without a goal; an objective that is not a simulation).
    """

    objective: float
    fell: bool = False
    cpu_seconds: float = 0.0
    error: str | None = None
    cut: bool = False
    sim_seconds: float = 0.0
    fall_time: float | None = None
    fall_direction: str | None = None
    task_success: bool | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EvalOutcome:
        return cls(
            objective=float(d["objective"]),
            fell=bool(d.get("fell", False)),
            cpu_seconds=float(d.get("cpu_seconds", 0.0)),
            error=d.get("error"),
            cut=bool(d.get("cut", False)),
            sim_seconds=float(d.get("sim_seconds", 0.0)),
            fall_time=_opt_float(d.get("fall_time")),
            fall_direction=d.get("fall_direction"),
            task_success=None if d.get("task_success") is None else bool(d["task_success"]),
        )


def _opt_float(v: Any) -> float | None:
    return None if v is None else float(v)


__all__ = ["FAILED_OBJECTIVE", "EvalOutcome"]


class Objective(Protocol):
    """A candidate's objective: `fn(params) -> EvalOutcome | float` (a float is wrapped into
    an outcome), deterministic, and picklable for a process pool (a top-level function or an
    instance of a top-level class). One that may be cut is a `CuttableObjective`."""

    def __call__(self, params: Any, /) -> EvalOutcome | float: ...


class CuttableObjective(ABC):
    """An objective that may stop early: `fn(params, stop_above=read)` calls `read()` as it
    goes (a bound; inf: none) and stops once its lower bound of the objective exceeds it,
    returning that bound with `cut=True` (`optim.rankcut`). Executors cut only these (by type:
    an objective declares it by deriving from this class)."""

    @abstractmethod
    def __call__(self, params: Any, /,
                 stop_above: Callable[[], float] | None = None) -> EvalOutcome:
        """The outcome of `params`, stopped early once its lower bound exceeds `stop_above()`."""
