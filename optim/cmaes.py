"""CMA-ES with the paper's stopping rules (section 4.1, 5.2), deterministic and picklable.

`CmaOptimizer` wraps `cma.CMAEvolutionStrategy` in ask/tell form:

    opt = CmaOptimizer(dim, seed=1, rules=StopRules.from_config(spec.optimize))
    while opt.stop() is None:
        xs = opt.ask()                      # list of np.ndarray in [lower, upper]^dim
        stats = opt.tell(xs, [f(x) for x in xs])

Contracts:
  * The optimizer owns its random stream: `randn=np.random.RandomState(seed).randn` is given
    to pycma, so the global `np.random` state is never read nor written, and the same seed with
    the same objective values gives the same candidates. `dumps()` pickles the whole state
    (strategy, RNG, bookkeeping, history); `loads()` continues bit-identically.
  * Bounds [lower, upper] are enforced by pycma's boundary transformation: every asked
    candidate lies inside them. Warm start: pass `x0` (e.g. an earlier result's params).
  * Objectives are minimised. NaN/inf objectives are replaced by `FAILED_OBJECTIVE` before
    pycma sees them (they rank worst).
  * `stop()` returns the name of the first rule that fires, checked in this order, or None:
      "threshold"        best objective so far <= rules.threshold (paper: early exit);
      "max_evaluations"  evaluations >= rules.max_evaluations (checked between generations,
                         so the last generation may overshoot the cap by < popsize);
      "slow_convergence" evaluations >= rules.min_evaluations and the best objective so far
                         improved by less than `improvement` (relative) over the last `window`
                         iterations: (f[i - window] - f[i]) / |f[i - window]| < improvement,
                         needs at least window + 1 generations;
      "cma:<key>"        pycma's own termination (tolfun, tolx, tolstagnation, ...).
"""

from __future__ import annotations

import math
import pickle
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

with warnings.catch_warnings():  # cma warns when matplotlib is missing; we never plot
    warnings.simplefilter("ignore")
    import cma

from optim.errors import CheckpointError, ParamsError
from optim.outcome import FAILED_OBJECTIVE

if TYPE_CHECKING:
    from sim.spec import OptimizeConfig

#: Paper defaults (section 4.1 / 5.2).
DEFAULT_MIN_EVALUATIONS = 700
DEFAULT_WINDOW_ITERATIONS = 100
DEFAULT_IMPROVEMENT = 0.05  # relative
DEFAULT_MAX_EVALUATIONS = 2000
DEFAULT_SIGMA0 = 0.2  # in units of the [0, 1] box (paper: Hansen's recommendation)
_PICKLE_FORMAT = "cmrt-cma/1"


#: Fewest coordinates a search may have: pycma's diagonal-decoding update fails in 1-D.
MIN_DIMENSION = 2


@dataclass(frozen=True)
class StopRules:
    """The paper's stopping rules (see module docstring for the exact semantics)."""

    threshold: float | None = None
    min_evaluations: int = DEFAULT_MIN_EVALUATIONS
    window: int = DEFAULT_WINDOW_ITERATIONS
    improvement: float = DEFAULT_IMPROVEMENT
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS

    def __post_init__(self) -> None:
        if self.window < 1:
            raise ValueError("StopRules.window must be >= 1 iteration")
        if not 0.0 < self.improvement < 1.0:
            raise ValueError("StopRules.improvement must be in (0, 1)")
        if self.max_evaluations < 1 or self.min_evaluations < 0:
            raise ValueError("StopRules: max_evaluations >= 1 and min_evaluations >= 0")

    @classmethod
    def from_config(cls, cfg: OptimizeConfig) -> StopRules:
        """Rules from a spec's `optimize` block."""
        return cls(
            threshold=cfg.threshold,
            min_evaluations=cfg.min_evaluations,
            window=cfg.window,
            improvement=cfg.improvement,
            max_evaluations=cfg.max_evaluations,
        )

    def slow(self, best_so_far: Sequence[float], evaluations: int) -> bool:
        """The slow-convergence rule after a generation: `best_so_far` is the run's best so
        far after each generation up to this one (oldest first; only the last `window` + 1
        are read), `evaluations` the count after it (see the module docstring)."""
        if evaluations < self.min_evaluations or len(best_so_far) <= self.window:
            return False
        then = best_so_far[-1 - self.window]
        now = best_so_far[-1]
        return (then - now) / max(abs(then), 1e-300) < self.improvement

    def first_stop(
        self, history: Sequence[GenerationStats | dict[str, Any]]
    ) -> tuple[int, str] | None:
        """Where these rules would have stopped a run with this history: (index of the last
        generation run, rule name), or None if none fires within it. Exact for the threshold,
        the cap and slow convergence (they read only the best so far and the evaluation
        count, as `CmaOptimizer.stop` does); pycma's own terminations are not replayed.
        A history from a run with other rules is a valid input: the rules do not change the
        search, only where it ends."""
        best: list[float] = []
        for i, h in enumerate(history):
            d = h if isinstance(h, dict) else asdict(h)
            best.append(float(d["best_so_far"]))
            evaluations = int(d["evaluations"])
            if self.threshold is not None and best[-1] <= self.threshold:
                return i, "threshold"
            if evaluations >= self.max_evaluations:
                return i, "max_evaluations"
            if self.slow(best, evaluations):
                return i, "slow_convergence"
        return None


@dataclass(frozen=True)
class GenerationStats:
    """Figures of one told generation (objective values; sigma in [0, 1]-box units)."""

    iteration: int  # 1-based
    evaluations: int  # cumulative
    best: float  # this generation
    median: float
    worst: float  # a lower bound of it when the last was cut early (optim.rankcut)
    sigma: float
    best_so_far: float

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GenerationStats:
        return cls(
            iteration=int(d["iteration"]),
            evaluations=int(d["evaluations"]),
            best=float(d["best"]),
            median=float(d["median"]),
            worst=float(d["worst"]),
            sigma=float(d["sigma"]),
            best_so_far=float(d["best_so_far"]),
        )


@dataclass
class _State:
    es: Any
    rules: StopRules
    dim: int
    seed: int
    lower: float
    upper: float
    best_x: np.ndarray | None = None
    best_f: float = math.inf
    evaluations: int = 0
    iterations: int = 0
    history: list[GenerationStats] = field(default_factory=list)
    pending: int = 0  # candidates asked and not yet told


class CmaOptimizer:
    """Ask/tell CMA-ES over [lower, upper]^dim with its own RNG (see module docstring)."""

    def __init__(
        self,
        dim: int,
        *,
        seed: int,
        x0: Sequence[float] | np.ndarray | None = None,
        sigma0: float = DEFAULT_SIGMA0,
        popsize: int | None = None,
        rules: StopRules | None = None,
        lower: float = 0.0,
        upper: float = 1.0,
    ) -> None:
        if dim < MIN_DIMENSION:
            raise ParamsError(f"CMA-ES dimension must be >= {MIN_DIMENSION} (pycma's update "
                              f"fails on one coordinate), got {dim}")
        if not upper > lower:
            raise ParamsError("CMA-ES bounds: upper must be greater than lower")
        if x0 is None:
            start = np.full(dim, 0.5 * (lower + upper))
        else:
            start = np.asarray(x0, dtype=float).reshape(-1)
            if len(start) != dim or not np.all(np.isfinite(start)):
                raise ParamsError(f"x0: expected {dim} finite numbers, got {len(start)}")
            start = np.clip(start, lower, upper)
        opts: dict[str, Any] = {
            "bounds": [lower, upper],
            "verbose": -9,
            "verb_log": 0,
            "verb_disp": 0,
            "seed": np.nan,  # pycma must not touch np.random: the RNG is ours
            "randn": np.random.RandomState(int(seed)).randn,
        }
        if popsize is not None:
            opts["popsize"] = int(popsize)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            es = cma.CMAEvolutionStrategy(start, float(sigma0), opts)
        self._s = _State(
            es=es,
            rules=rules or StopRules(),
            dim=dim,
            seed=int(seed),
            lower=float(lower),
            upper=float(upper),
        )

    # -- read-only views --------------------------------------------------------------------
    @property
    def popsize(self) -> int:
        return int(self._s.es.popsize)

    @property
    def dim(self) -> int:
        return self._s.dim

    @property
    def seed(self) -> int:
        return self._s.seed

    @property
    def rules(self) -> StopRules:
        return self._s.rules

    @property
    def sigma(self) -> float:
        return float(self._s.es.sigma)

    @property
    def mean(self) -> np.ndarray:
        """The strategy's current mean (a copy; pycma's genotype coordinates)."""
        return np.array(self._s.es.mean, dtype=float)

    @property
    def cut_margin(self) -> float | None:
        """The margin `optim.rankcut` needs for an early stop of a generation's certain last
        (pycma's tolfun), None when this strategy's options allow no cut."""
        from optim.rankcut import cut_margin

        return cut_margin(self._s.es)

    @property
    def best_x(self) -> np.ndarray | None:
        """Best candidate told so far (a copy), None before the first tell."""
        return None if self._s.best_x is None else self._s.best_x.copy()

    @property
    def best_f(self) -> float:
        """Best objective told so far (inf before the first tell)."""
        return self._s.best_f

    @property
    def evaluations(self) -> int:
        return self._s.evaluations

    @property
    def iterations(self) -> int:
        return self._s.iterations

    @property
    def history(self) -> list[GenerationStats]:
        return list(self._s.history)

    # -- ask / tell ---------------------------------------------------------------------------
    def ask(self) -> list[np.ndarray]:
        """A new generation of `popsize` candidates, each inside the bounds."""
        xs = self._s.es.ask()
        self._s.pending = len(xs)
        return [np.array(x, dtype=float) for x in xs]

    def tell(
        self, candidates: Sequence[np.ndarray], objectives: Sequence[float]
    ) -> GenerationStats:
        """Report the objectives of the candidates of the last `ask()` (same order)."""
        if len(candidates) != len(objectives):
            raise ParamsError(
                f"tell: {len(candidates)} candidates but {len(objectives)} objective values"
            )
        if len(candidates) == 0:
            raise ParamsError("tell: empty generation")
        fs = [
            float(f) if f is not None and math.isfinite(float(f)) else FAILED_OBJECTIVE
            for f in objectives
        ]
        xs = [np.asarray(x, dtype=float) for x in candidates]
        s = self._s
        s.es.tell(xs, fs)
        s.pending = 0
        s.evaluations += len(fs)
        s.iterations += 1
        i = int(np.argmin(fs))
        if fs[i] < s.best_f:
            s.best_f = fs[i]
            s.best_x = xs[i].copy()
        stats = GenerationStats(
            iteration=s.iterations,
            evaluations=s.evaluations,
            best=fs[i],
            median=float(np.median(fs)),
            worst=float(np.max(fs)),
            sigma=float(s.es.sigma),
            best_so_far=s.best_f,
        )
        s.history.append(stats)
        return stats

    def stop(self) -> str | None:
        """Name of the stopping rule that fires now, or None (order: see module docstring)."""
        s, r = self._s, self._s.rules
        if s.iterations == 0:
            return None
        if r.threshold is not None and s.best_f <= r.threshold:
            return "threshold"
        if s.evaluations >= r.max_evaluations:
            return "max_evaluations"
        if r.slow([h.best_so_far for h in s.history[-1 - r.window:]], s.evaluations):
            return "slow_convergence"
        own = s.es.stop()
        if own:
            return "cma:" + str(next(iter(own)))
        return None

    # -- persistence ----------------------------------------------------------------------------
    def dumps(self) -> bytes:
        """Pickled state (strategy, RNG, best, counters, history). Trusted storage only."""
        return pickle.dumps({"format": _PICKLE_FORMAT, "state": self._s}, protocol=4)

    @classmethod
    def loads(cls, data: bytes) -> CmaOptimizer:
        """Restore a `dumps()` snapshot; continues exactly as the original would have."""
        try:
            obj = pickle.loads(data)
        except Exception as err:  # noqa: BLE001 - any unpickling failure is a bad snapshot
            raise CheckpointError(f"cannot restore the CMA-ES state: {err}") from None
        if not isinstance(obj, dict) or obj.get("format") != _PICKLE_FORMAT:
            raise CheckpointError("not a CMA-ES state snapshot (format tag missing or wrong)")
        self = cls.__new__(cls)
        self._s = obj["state"]
        return self

    def __repr__(self) -> str:
        return (
            f"CmaOptimizer(dim={self.dim}, popsize={self.popsize}, iterations={self.iterations}, "
            f"evaluations={self.evaluations}, best_f={self.best_f:.6g})"
        )


__all__ = [
    "DEFAULT_IMPROVEMENT",
    "DEFAULT_MAX_EVALUATIONS",
    "DEFAULT_MIN_EVALUATIONS",
    "DEFAULT_SIGMA0",
    "DEFAULT_WINDOW_ITERATIONS",
    "FAILED_OBJECTIVE",
    "CmaOptimizer",
    "GenerationStats",
    "StopRules",
]
