"""The simulation objective: params in [0, 1]^d -> CMRT spline -> one clip simulation, and the
process's one cache of specs.

Contracts:
  * `SPECS` is this process's one spec cache: spec hash (`sim.spec.CanonicalSpec.hash`) ->
    the typed spec, and, built on first use, its simulator (one `sim.rollout.Rollout`) and the
    objectives made from it. It keeps the `SPEC_CACHE_SIZE` most recently used specs and the
    simulators of the `SIMULATOR_CACHE_SIZE` most recently used ones (each holds an ODE
    world); the simulator resets its world between runs, so results are deterministic and
    independent of call order. A process parses a spec only on a miss: at most once while the
    spec stays among the recently used.
  * `SimObjective(spec)` is small and picklable: it carries only the spec's hash and canonical
    JSON; in another process it finds the typed spec in `SPECS` by the hash, and parses the
    text only there on a miss.
  * `SimObjective(spec)(params) -> EvalOutcome` (objective: the paper's CP-error 2-norm in
    metres, with the simulator's fall penalty; fell; cpu_seconds).
    `params=None` evaluates the clip without any CMRT.
  * `evaluate_params(spec, params, traces=False) -> sim.clip_result.Evaluation` is the same
    evaluation with the full record (optionally per-step traces), using the same cache.
  * `sim.rollout` is imported lazily, so `optim` imports without it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cmrt.canonical import canonical_json, text_hash
from cmrt.lru import LRU
from optim.outcome import CuttableObjective, EvalOutcome
from optim.robust import split_point
from optim.spline import decode
from sim.robust import variant_document, variant_values
from sim.spec import (
    CanonicalSpec,
    TaskSpec,
    canonical_spec,
    parse_spec,
    stored_spec,
    text_spec,
)

if TYPE_CHECKING:
    from sim.clip_result import Evaluation

#: Specs kept per process (a typed spec is a few kB).
SPEC_CACHE_SIZE = 64
#: Simulators kept per process (each holds an ODE world).
SIMULATOR_CACHE_SIZE = 4


@dataclass
class _Entry:
    canonical: Any  # CanonicalSpec, or another typed document (`SpecCache.typed`)
    simulator: Any = None
    #: A robust spec's variants' simulators by index (kept and dropped with `simulator`).
    variants: dict[int, Any] = field(default_factory=dict)
    objective: Any = None


class SpecCache:
    """Spec hash -> typed spec, its simulator and objectives (see the module docstring).
    Thread-safe: the API's request threads and its drivers share one."""

    def __init__(self, size: int = SPEC_CACHE_SIZE,
                 simulators: int = SIMULATOR_CACHE_SIZE) -> None:
        self.size, self.simulators = size, simulators
        self._d: LRU[str, _Entry] = LRU(size)
        self._sims: LRU[str, None] = LRU(simulators)  # hashes whose simulator is built
        # re-entrant: an objective made under it puts its spec; a load under it parses once
        self._lock = threading.RLock()

    def __len__(self) -> int:
        return len(self._d)

    def __contains__(self, hash: object) -> bool:
        return hash in self._d

    def _entry(self, hash: str, load: Callable[[], CanonicalSpec]) -> _Entry:
        with self._lock:
            hit = self._d.get(hash)
            if hit is not None:
                return hit
            entry = _Entry(load())
            for old, _ in self._d.put(hash, entry):
                self._sims.pop(old)
            return entry

    def put(self, canonical: CanonicalSpec) -> CanonicalSpec:
        """Keep a spec this process has in typed form already (no parse); the cached one if its
        hash is known."""
        return self._entry(canonical.hash, lambda: canonical).canonical

    def get(self, hash: str, load: Callable[[], CanonicalSpec]) -> CanonicalSpec:
        """The spec of `hash`; `load()` (which parses it) runs only on a miss."""
        return self._entry(hash, load).canonical

    def typed(self, hash: str, load: Callable[[], Any]) -> Any:
        """Any other typed document kept under its hash (a family request: its
        `optim.family.spec.FamilySpec`); `load()` runs only on a miss."""
        return self._entry(hash, load).canonical

    def stored(self, document: Mapping[str, Any], hash: str, source: str = "<spec>"
               ) -> CanonicalSpec:
        """The spec of a document stored with its hash (a job's), parsed only on a miss."""
        return self.get(hash, lambda: stored_spec(document, hash, source))

    def simulator(self, canonical: CanonicalSpec, variant: int | None = None) -> Any:
        """The spec's `Rollout` (or that of its robust variant `variant`, `sim.robust`), built
        on first use. A spec's variants count as one simulator of the cache: a robust job
        evaluates all K in turn."""
        with self._lock:
            entry = self._entry(canonical.hash, lambda: canonical)
            if variant is None and entry.simulator is None:
                entry.simulator = _rollout(entry.canonical.spec)
            elif variant is not None and variant not in entry.variants:
                entry.variants[variant] = _rollout(_variant_spec(entry.canonical, variant))
            for old, _ in self._sims.put(canonical.hash, None):
                dropped = self._d.peek(old)
                if dropped is not None:
                    dropped.simulator = None
                    dropped.variants = {}
            return entry.simulator if variant is None else entry.variants[variant]

    def objective(self, canonical: CanonicalSpec) -> SimObjective:
        """The spec's objective (its `SimObjective`), made once per spec."""
        with self._lock:
            entry = self._entry(canonical.hash, lambda: canonical)
            if entry.objective is None:
                entry.objective = SimObjective(entry.canonical)
            return entry.objective

    def clear(self) -> None:
        with self._lock:
            self._d.clear()
            self._sims.clear()


def _rollout(spec: TaskSpec) -> Any:
    from sim.rollout import Rollout  # lazy: heavy, absent in a numerics-only setup

    return Rollout(spec)


def _variant_spec(canonical: CanonicalSpec, k: int) -> TaskSpec:
    """Variant k of a robust spec (`sim.robust.variant_document`), validated."""
    robust = canonical.spec.optimize.robust
    values = variant_values(robust)[k]
    return parse_spec(variant_document(canonical.document, values),
                      f"{canonical.spec.name} variant {k}")


#: This process's one spec cache.
SPECS = SpecCache()


def _canonical(spec: TaskSpec | CanonicalSpec | Mapping[str, Any]) -> CanonicalSpec:
    if isinstance(spec, CanonicalSpec):
        return spec
    if isinstance(spec, Mapping):  # a spec document (validated upstream): parsed on a miss
        text = canonical_json(spec)
        hash = text_hash(text)
        return SPECS.get(hash, lambda: text_spec(text, hash, "<objective spec>"))
    return canonical_spec(spec)


class SimObjective(CuttableObjective):
    """Picklable objective for one spec (it may be cut: `stop_above`); see module docstring."""

    def __init__(self, spec: TaskSpec | CanonicalSpec | Mapping[str, Any]) -> None:
        canonical = SPECS.put(_canonical(spec))
        self.spec_hash = canonical.hash
        self._canonical: CanonicalSpec | None = canonical  # in this process: never parsed
        self._text: str | None = None

    @property
    def spec_json(self) -> str:
        """The spec's canonical JSON (what a pickled objective carries)."""
        return self._text if self._canonical is None else self._canonical.text

    def _load(self) -> CanonicalSpec:
        if self._canonical is not None:
            return self._canonical
        assert self._text is not None
        return text_spec(self._text, self.spec_hash, "<objective spec>")

    def canonical(self) -> CanonicalSpec:
        """The typed spec (parsed from the carried text only on a miss in this process)."""
        return SPECS.get(self.spec_hash, self._load)

    @property
    def spec(self) -> TaskSpec:
        return self.canonical().spec

    def evaluation(
        self, params: Sequence[float] | np.ndarray | None, traces: bool = False,
        stop_above: Callable[[], float] | None = None,
    ) -> Evaluation:
        """The full `Evaluation` of `params` (None: no CMRT); `stop_above`: see
        `sim.rollout.Rollout.run`."""
        canonical = self.canonical()
        variant = None
        if params is not None:
            params, variant = split_point(canonical.spec, params)
        sim = SPECS.simulator(canonical, variant)
        cmrt = None if params is None else decode(sim.spec, params)
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
        return {"spec_hash": self.spec_hash, "spec_json": self.spec_json}

    def __setstate__(self, state: dict[str, str]) -> None:
        self.spec_hash, self._text = state["spec_hash"], state["spec_json"]
        self._canonical = None

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SimObjective) and other.spec_hash == self.spec_hash

    def __hash__(self) -> int:
        return hash(self.spec_hash)

    def __repr__(self) -> str:
        return f"SimObjective({self.spec.name!r})"


def evaluate_params(
    spec: TaskSpec | CanonicalSpec | Mapping[str, Any], params: Sequence[float] | np.ndarray | None,
    traces: bool = False,
) -> Evaluation:
    """Simulate `spec` with the CMRT decoded from `params` (None: without CMRT)."""
    return SimObjective(spec).evaluation(params, traces=traces)


__all__ = ["SIMULATOR_CACHE_SIZE", "SPECS", "SPEC_CACHE_SIZE", "SimObjective", "SpecCache",
           "evaluate_params"]
