"""Cheap, picklable, deterministic objectives for the tests (no physics).

Each is a top-level class instance, so it can be sent to `PoolExecutor` workers (their
processes import it as `synthetic`: pytest puts tests/ on the path, and a spawned or forked
process inherits it).
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass

import numpy as np

from optim.outcome import CuttableObjective, EvalOutcome


@dataclass(frozen=True)
class Sphere:
    """f(x) = offset + sum((x - centre)^2); `fall_above` marks outcomes above it as falls."""

    centre: float = 0.3
    offset: float = 0.0
    fall_above: float | None = None
    sleep: float = 0.0  # s of wall time per call, to exercise pools

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        if self.sleep:
            time.sleep(self.sleep)
        f = self.offset + float(np.sum((np.asarray(x, dtype=float) - self.centre) ** 2))
        fell = self.fall_above is not None and f > self.fall_above
        return EvalOutcome(objective=f, fell=fell, cpu_seconds=0.0)


def _hash_uniform(x: np.ndarray, salt: int) -> float:
    """A deterministic pseudo-random number in [0, 1) from the bytes of x (no global RNG)."""
    h = hashlib.blake2b(
        np.asarray(x, dtype=np.float64).tobytes(), digest_size=8, key=salt.to_bytes(8, "little")
    )
    return int.from_bytes(h.digest(), "little") / 2.0**64


@dataclass(frozen=True)
class NoisyFlat:
    """f(x) = level + amplitude * u(x), u deterministic pseudo-noise in [0, 1): no progress."""

    level: float = 1.0
    amplitude: float = 0.01
    salt: int = 0

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        return EvalOutcome(objective=self.level + self.amplitude * _hash_uniform(x, self.salt))


@dataclass(frozen=True)
class RunningSum(CuttableObjective):
    """A clip-like objective: sqrt of a sum of `steps` squared errors e_k = (x_j - centre) *
    (1 + k / steps) over the coordinates in turn, so the running sum grows as a simulated
    clip's does. Takes `stop_above` like `optim.objective.SimObjective`: read every
    `check_every` steps, it stops once sqrt(running sum) exceeds it (`cut=True`, the running
    norm as the objective). `sim_seconds` counts the steps done (1 ms each)."""

    centre: float = 0.3
    steps: int = 400
    check_every: int = 10
    #: s of wall time per check, times 1 + 5 |x - centre|: worse candidates take longer, so
    #: a pool's last unfinished candidate is often the worst (exercises the pool's cut path).
    sleep: float = 0.0
    #: s to wait, before the first step, for a finite `stop_above` (a pool posts a bound to
    #: the last candidate of a generation only once every other one is done): a candidate known
    #: to be evaluated last then meets its bound from its first check, as in a serial run, so
    #: whether it is cut depends on the values alone, never on timing. Changes no value.
    hold: float = 0.0

    def __call__(self, x: np.ndarray, stop_above=None) -> EvalOutcome:  # noqa: ANN001
        d = np.asarray(x, dtype=float) - self.centre
        pause = self.sleep * (1.0 + 5.0 * float(np.sqrt(d @ d)))
        if stop_above is not None and self.hold > 0:
            until = time.monotonic() + self.hold
            while stop_above() == float("inf") and time.monotonic() < until:
                time.sleep(1e-3)
        sq = 0.0
        for k in range(self.steps):
            if k % self.check_every == 0 and pause:
                time.sleep(pause)
            if stop_above is not None and k % self.check_every == 0:
                lb = float(np.sqrt(sq))
                if lb > stop_above():
                    return EvalOutcome(objective=lb, cut=True, sim_seconds=k * 1e-3)
            e = float(d[k % len(d)]) * (1.0 + k / self.steps)
            sq += e * e
        return EvalOutcome(objective=float(np.sqrt(sq)), sim_seconds=self.steps * 1e-3)


@dataclass(frozen=True)
class LineFamily:
    """One member of a synthetic family: f(x) = offset + sum((x - c)^2), whose optimum
    c_j = base + slope * value * (j + 1) / d moves along a straight line of the box as
    `value` changes (a family with a one-component basis); `sleep`: s of wall time per call."""

    value: float
    base: float = 0.3
    slope: float = 0.05
    offset: float = 0.1
    sleep: float = 0.0

    def centre(self, dim: int) -> np.ndarray:
        return self.base + self.slope * self.value * (np.arange(dim) + 1.0) / dim

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        if self.sleep:
            time.sleep(self.sleep)
        x = np.asarray(x, dtype=float)
        f = self.offset + float(np.sum((x - self.centre(len(x))) ** 2))
        return EvalOutcome(objective=f, cpu_seconds=0.0)


@dataclass(frozen=True)
class RaiseAbove:
    """Sphere that raises ValueError when x[0] > limit (an evaluation error)."""

    limit: float = 0.5

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        if float(x[0]) > self.limit:
            raise ValueError(f"x[0] = {float(x[0]):.3f} above {self.limit}")
        return EvalOutcome(objective=float(np.sum((np.asarray(x) - 0.3) ** 2)))


@dataclass(frozen=True)
class KillWorker:
    """Kills the process evaluating it (simulates a crashed or OOM-killed worker)."""

    exit_code: int = 13

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        os._exit(self.exit_code)


@dataclass(frozen=True)
class Sleep:
    """Sleeps `seconds` then returns 0 (exercises batch timeouts)."""

    seconds: float = 10.0

    def __call__(self, x: np.ndarray) -> EvalOutcome:
        time.sleep(self.seconds)
        return EvalOutcome(objective=0.0)


__all__ = ["KillWorker", "LineFamily", "NoisyFlat", "RaiseAbove", "RunningSum", "Sleep", "Sphere"]
