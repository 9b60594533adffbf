"""`EvalOutcome`: the result of evaluating one candidate (light module: numpy-free imports).

Kept apart from `optim.executors` and `optim.cmaes` so pool worker processes and objectives
import it without pulling in pycma (which takes ~1.5 s to import).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

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
