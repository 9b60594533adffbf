"""Physics core: planar characters in ODE, the momentum balance controller, task clips.

Public entry points: `load_spec`, `parse_spec`, `TaskSpec`, `evaluate`, `Evaluation`.
Imports no web, queue or database code; the ODE parts (`sim.rollout`, `sim.physics`) are
imported only when `evaluate` is first used.
"""

from typing import Any

from sim.clip_result import Evaluation
from sim.errors import CharacterError, SimError, SpecError
from sim.spec import TaskSpec, load_spec, parse_spec


def evaluate(spec: TaskSpec, cmrt: Any = None, traces: bool = False) -> Evaluation:
    """Simulate one clip of `spec` with the CMRT callable (see sim.rollout.evaluate)."""
    from sim.rollout import evaluate as _evaluate

    return _evaluate(spec, cmrt, traces)


__all__ = ["CharacterError", "Evaluation", "SimError", "SpecError", "TaskSpec", "evaluate",
           "load_spec", "parse_spec"]
