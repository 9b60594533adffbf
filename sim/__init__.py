"""Physics core: planar characters in ODE, the momentum balance controller, task clips.

Public entry points: `load_spec`, `parse_spec`, `TaskSpec`, `evaluate`, `Evaluation`.
Imports no web, queue or database code.
"""

from sim.errors import CharacterError, SimError, SpecError
from sim.spec import TaskSpec, load_spec, parse_spec

__all__ = ["CharacterError", "SimError", "SpecError", "TaskSpec", "load_spec", "parse_spec"]
