"""The simulation objective: params in [0, 1]^d -> CMRT spline -> one clip simulation.

Contracts:
  * `SimObjective(spec)` is small and picklable: it holds only the spec's canonical JSON.
    In each process it lazily builds ONE `sim.rollout.Rollout` per distinct spec (module-level
    cache keyed by that JSON, at most `SIMULATOR_CACHE_SIZE` entries, least recently used
    dropped) and reuses it for every call; the simulator resets its world between runs, so
    results are deterministic and independent of call order.
  * `SimObjective(spec)(params) -> EvalOutcome` (objective: the paper's CP-error 2-norm in
    metres, with the simulator's fall penalty; fell; cpu_seconds).
    `params=None` evaluates the clip without any CMRT.
  * `evaluate_params(spec, params, traces=False) -> sim.evaluation.Evaluation` is the same
    evaluation with the full record (optionally per-step traces), using the same cache.
  * `sim.rollout` is imported lazily, so `optim` imports without it.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from optim.outcome import EvalOutcome
from optim.spline import decode

if TYPE_CHECKING:
    from sim.evaluation import Evaluation
    from sim.spec import TaskSpec

#: Rollouts kept per process (each holds an ODE world).
SIMULATOR_CACHE_SIZE = 4

_CACHE: OrderedDict[str, tuple[Any, Any]] = OrderedDict()  # spec JSON -> (TaskSpec, Rollout)


def spec_json(spec: TaskSpec | Mapping[str, Any]) -> str:
    """Canonical JSON of a spec (sorted keys): the cache key and the picklable form."""
    data = spec.model_dump(mode="json") if hasattr(spec, "model_dump") else dict(spec)
    return json.dumps(data, sort_keys=True, separators=(",", ":"))


def _parse(text: str) -> TaskSpec:
    from sim.spec import parse_spec

    return parse_spec(json.loads(text), "<objective spec>")


def _cached(text: str) -> tuple[TaskSpec, Any]:
    """(spec, Rollout) for this spec JSON in this process, built on first use."""
    hit = _CACHE.get(text)
    if hit is not None:
        _CACHE.move_to_end(text)
        return hit
    from sim.rollout import Rollout  # lazy: heavy, and may not exist in a numerics-only setup

    spec = _parse(text)
    entry = (spec, Rollout(spec))
    _CACHE[text] = entry
    while len(_CACHE) > SIMULATOR_CACHE_SIZE:
        _CACHE.popitem(last=False)
    return entry


def clear_cache() -> None:
    """Drop this process's cached simulators."""
    _CACHE.clear()


class SimObjective:
    """Picklable objective for one spec; see module docstring."""

    def __init__(self, spec: TaskSpec | Mapping[str, Any]) -> None:
        self.spec_json = spec_json(spec)

    @property
    def spec(self) -> TaskSpec:
        return _parse(self.spec_json)

    #: `__call__` takes `stop_above` (optim.rankcut's early stop of a certain last).
    supports_cut = True

    def evaluation(
        self, params: Sequence[float] | np.ndarray | None, traces: bool = False,
        stop_above: Callable[[], float] | None = None,
    ) -> Evaluation:
        """The full `Evaluation` of `params` (None: no CMRT); `stop_above`: see
        `sim.rollout.Rollout.run`."""
        spec, sim = _cached(self.spec_json)
        cmrt = None if params is None else decode(spec, params)
        if stop_above is None:
            return sim.run(cmrt, traces=traces)
        return sim.run(cmrt, traces=traces, stop_above=stop_above)

    def __call__(
        self, params: Sequence[float] | np.ndarray | None,
        stop_above: Callable[[], float] | None = None,
    ) -> EvalOutcome:
        ev = self.evaluation(params, stop_above=stop_above)
        return EvalOutcome(
            objective=float(ev.objective), fell=bool(ev.fell), cpu_seconds=float(ev.cpu_seconds),
            cut=bool(ev.cut), sim_seconds=float(ev.sim_seconds),
            fall_time=None if ev.fall_time is None else float(ev.fall_time),
            fall_direction=ev.fall_direction, task_success=ev.task_success,
        )

    def __getstate__(self) -> dict[str, str]:
        return {"spec_json": self.spec_json}

    def __setstate__(self, state: dict[str, str]) -> None:
        self.spec_json = state["spec_json"]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SimObjective) and other.spec_json == self.spec_json

    def __hash__(self) -> int:
        return hash(self.spec_json)

    def __repr__(self) -> str:
        return f"SimObjective({json.loads(self.spec_json).get('name')!r})"


def evaluate_params(
    spec: TaskSpec, params: Sequence[float] | np.ndarray | None, traces: bool = False
) -> Evaluation:
    """Simulate `spec` with the CMRT decoded from `params` (None: without CMRT)."""
    return SimObjective(spec).evaluation(params, traces=traces)


__all__ = ["SIMULATOR_CACHE_SIZE", "SimObjective", "clear_cache", "evaluate_params", "spec_json"]
