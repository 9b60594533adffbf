"""What-if simulations: one clip of a spec with a chosen CMRT, run in a process of the API's
own small pool (`SimulationPool`) so a crash or a diverging ODE never takes the server down.

`run_clip` is the picklable body that runs in the pool process; `SimulationPool`, over the one
process pool (`optim.procpool.SlotPool`: its processes end with the API, even when it is
killed), bounds how many clips run or wait at once (more: 503 with Retry-After) and how long one
may take (`Settings.eval_time_limit`: past it the clip's process is killed, the others run on),
and turns every way a clip can fail into a `failed` outcome with the reason: the simulation
diverged (sim's DivergenceError), the process died, the time limit.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
from collections.abc import Iterator
from typing import Any

from optim.objective import SimObjective
from optim.procpool import SIMULATOR_PRELOAD, SlotPool, TimeLimitError, WorkerDiedError
from optim.spline import decode
from sim.errors import SimError
from sim.export import export_text
from sim.replay import ReplayClip, build_replay

log = logging.getLogger("cmrt.service.simulations")

#: Clips waiting for a pool process beyond the running ones before new requests get 503.
MAX_WAITING = 4
#: The outcome fields copied from sim's Evaluation.
OUTCOME_FIELDS = ("objective", "fell", "fall_time", "fall_reason", "fall_direction",
                  "task_success", "task_penalty", "error_norm", "max_abs_error", "sim_seconds",
                  "cpu_seconds", "steps", "contact_steps", "cmrt_released_at")


#: How a clip fails in a pool process: the simulator's refusals (DivergenceError, ...), and
#: numbers gone non-finite past its checks (numpy's LinAlgError is a ValueError): the clip
#: diverged between two checks.
CLIP_FAILURES = (SimError, ArithmeticError, ValueError)


def clip_failure(err: Exception) -> dict[str, Any]:
    """The `failed` outcome of a clip that raised one of CLIP_FAILURES, with the reason."""
    if isinstance(err, SimError):
        return {"status": "failed", "error": f"{type(err).__name__}: {err}"}
    return {"status": "failed", "error": f"the simulation diverged ({type(err).__name__}: {err})"}


def _finite_or_none(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


def run_clip(spec_data: dict[str, Any], params: list[float] | None, traces: bool,
             frames: bool) -> dict[str, Any]:
    """Simulate one clip (in a pool process): `{"status": "done", ...outcome}` or
    `{"status": "failed", "error": ...}` when the simulator refuses or diverges."""
    try:
        ev = SimObjective(spec_data).evaluation(params, traces=traces or frames)
    except CLIP_FAILURES as err:
        return clip_failure(err)
    out: dict[str, Any] = {"status": "done"}
    out.update({k: _finite_or_none(getattr(ev, k)) for k in OUTCOME_FIELDS})
    full = ev.to_dict(include_traces=True)
    if traces:
        out["traces"] = full.get("traces")
    if frames:
        out["frames"] = full.get("frames")
    return out


def run_replay(spec_data: dict[str, Any], params: list[float] | None,
               about: dict[str, Any] | None, compare: bool) -> dict[str, Any]:
    """Simulate a clip for replay (in a pool process), recorded at the frame rate:
    `{"status": "done", "replay": <sim.replay document>}`, or `failed` as `run_clip`. With
    `params` and `compare`, the flat-spline clip (no anticipation) comes first, beside it."""
    obj = SimObjective(spec_data)
    spec = obj.spec
    clips = []
    try:
        if params is None or compare:
            clips.append(ReplayClip("no anticipation (flat spline)",
                                    obj.evaluation(None, traces=True), None, {"source": "none"}))
        if params is not None:
            clips.append(ReplayClip("with the CMRT", obj.evaluation(params, traces=True),
                                    decode(spec, params), about))
    except CLIP_FAILURES as err:
        return clip_failure(err)
    return {"status": "done", "replay": build_replay(spec, clips)}


def run_export(spec_data: dict[str, Any], params: list[float], fmt: str, fps: float
               ) -> dict[str, Any]:
    """Simulate the clip of `params` (in a pool process) and write its motion as `fmt` ("bvh"
    or "csv", `sim.export`) at `fps`: `{"status": "done", "text": ...}`, or `failed` as
    `run_clip`."""
    obj = SimObjective(spec_data)
    try:
        ev = obj.evaluation(params, traces=True)
        text = export_text(obj.spec.load_character(), ev, fmt, fps)
    except CLIP_FAILURES as err:
        return clip_failure(err)
    return {"status": "done", "text": text}


class SimulationBusyError(Exception):
    """Every pool process is busy and the waiting line is full."""


class SimulationPool:
    """A process pool of `workers` processes for what-if clips (started on first use)."""

    def __init__(self, workers: int = 1, time_limit: float = 600.0) -> None:
        self.workers = workers
        self.time_limit = time_limit
        self._pool: SlotPool | None = None
        self._lock = threading.Lock()
        self._in_flight = 0

    def _get(self) -> SlotPool:
        with self._lock:
            if self._pool is None:
                # forked from a fork server (never from this threaded server process) that
                # has imported the simulator, like the evaluation pool's: a clip's process
                # killed past its time limit is replaced in a fraction of a second
                self._pool = SlotPool(self.workers, start_method="forkserver",
                                      preload=SIMULATOR_PRELOAD, time_limit=self.time_limit)
            return self._pool

    def pids(self) -> list[int]:
        """The pool's processes (started ones)."""
        pool = self._pool
        return [] if pool is None else pool.pids()

    async def run(self, spec_data: dict[str, Any], params: list[float] | None, *, traces: bool,
                  frames: bool) -> dict[str, Any]:
        """One what-if clip (`run_clip`) in the pool."""
        return await self.call(run_clip, spec_data, params, traces, frames)

    async def call(self, fn: Any, *args: Any) -> dict[str, Any]:
        """`fn(*args)` (a picklable clip body answering `{"status": ...}`) in the pool, bounded
        as the module docstring says."""
        with self._admitted():
            task = self._get().submit(fn, *args)
            try:
                return await asyncio.wrap_future(task.future)
            except (TimeLimitError, WorkerDiedError) as err:
                return self._failure(err)

    def call_sync(self, fn: Any, *args: Any) -> dict[str, Any]:
        """`call` for a caller on a worker thread (a use case that simulates as it decides):
        the same bounds, waiting on this thread."""
        with self._admitted():
            task = self._get().submit(fn, *args)
            try:
                return task.future.result()
            except (TimeLimitError, WorkerDiedError) as err:
                return self._failure(err)

    def simulate(self, spec_data: dict[str, Any], params: list[float]) -> dict[str, Any]:
        """One clip's outcome without traces, waiting on this thread (`call_sync`)."""
        return self.call_sync(run_clip, spec_data, params, False, False)

    @contextlib.contextmanager
    def _admitted(self) -> Iterator[None]:
        with self._lock:
            if self._in_flight >= self.workers + MAX_WAITING:
                raise SimulationBusyError
            self._in_flight += 1
        try:
            yield
        finally:
            with self._lock:
                self._in_flight -= 1

    def _failure(self, err: Exception) -> dict[str, Any]:
        if isinstance(err, TimeLimitError):
            return {"status": "failed",
                    "error": f"the clip ran past the time limit of {self.time_limit:g} s"}
        log.error("simulation: the pool process died")
        return {"status": "failed", "error": "the simulation process died (crash or "
                                             "out of memory)"}

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.close()
