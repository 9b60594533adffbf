"""What-if simulations, replays and motion files: one clip of a spec with a chosen CMRT, run in
a process of the API's own small pool (`SimulationPool`) so a crash or a diverging ODE never
takes the server down.

The requests (`SimulationRequest`, `ReplayRequest`, the CMRT `CmrtChoice`) are typed here; the
use cases (`simulate`, `replay_cmrt`, `replay_job`, `replay_whatif`, `job_motion`) resolve the
CMRT (a library CMRT, a job's best candidate, inline parameters), run the clip body
(`optim.clips`) in the pool and refuse with `application.errors`: 404 an unknown id (the store's
NotFound), 409 a stored CMRT or job that cannot be replayed, 422 a request that breaks a rule,
503 every simulation process busy (`SimulationBusyError`, with Retry-After).

`SimulationPool`, over the one process pool (`optim.procpool.SlotPool`: its processes end with
the API, even when it is killed), bounds how many clips run or wait at once (more: 503) and how
long one may take (`Settings.eval_time_limit`: past it the clip's process is killed, the others
run on), and turns every way a clip can fail into a `failed` outcome with the reason: the
simulation diverged (sim's DivergenceError), the process died, the time limit.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from application.errors import ApplicationError, Busy, InvalidRequest, Missing, RequestConflict
from application.jobs import stored_job_spec
from optim.clips import run_clip, run_export, run_replay
from optim.errors import ParamsError
from optim.procpool import SIMULATOR_PRELOAD, SlotPool, TimeLimitError, WorkerDiedError
from optim.spline import check_params
from sim.errors import SpecError
from sim.export import DEFAULT_FPS, MAX_FPS, MIN_FPS
from sim.spec import TaskSpec, parse_spec
from store import NotFound, Repository

log = logging.getLogger("cmrt.service.simulations")

#: Clips waiting for a pool process beyond the running ones before new requests get 503.
MAX_WAITING = 4
#: Seconds a client is told to wait when every simulation process is busy.
RETRY_AFTER_S = 5
#: Longest inline CMRT parameter vector accepted (3 per knot, at most 16 knots).
MAX_CMRT_PARAMS = 48


# ---- the requests -----------------------------------------------------------------------------
class LibraryCmrtRef(BaseModel):
    """A CMRT of the library, by id."""

    model_config = ConfigDict(extra="forbid")
    source: Literal["library"]
    id: Annotated[str, Field(min_length=1, max_length=64)]


class JobBestCmrt(BaseModel):
    """The best candidate a job has found so far (or finished with)."""

    model_config = ConfigDict(extra="forbid")
    source: Literal["job"]
    id: Annotated[str, Field(min_length=1, max_length=64)]


class InlineCmrt(BaseModel):
    """Spline parameters given inline (the spec's `cmrt` parameterisation, values in [0, 1])."""

    model_config = ConfigDict(extra="forbid")
    source: Literal["params"]
    params: Annotated[list[Annotated[float, Field(strict=True, allow_inf_nan=False)]],
                      Field(min_length=1, max_length=MAX_CMRT_PARAMS)]


CmrtChoice = Annotated[LibraryCmrtRef | JobBestCmrt | InlineCmrt, Field(discriminator="source")]


class SimulationRequest(BaseModel):
    """One clip of `spec`, with the CMRT `cmrt` (null or absent: no anticipation)."""

    model_config = ConfigDict(extra="forbid")
    spec: TaskSpec
    cmrt: CmrtChoice | None = None
    traces: bool = Field(True, strict=True,
                         description="include the 1 kHz traces (t, cp, support, cm, ...)")
    frames: bool = Field(False, strict=True,
                         description="include the 100 Hz replay frames (body poses)")


class ReplayRequest(BaseModel):
    """A replay of one clip of `spec` with the CMRT `cmrt` (null: no anticipation only); with a
    CMRT and `compare` (the default), the flat-spline clip is simulated beside it."""

    model_config = ConfigDict(extra="forbid")
    spec: TaskSpec
    cmrt: CmrtChoice | None = None
    compare: bool = Field(True, strict=True,
                          description="add the clip without anticipation (flat spline)")


class Links(Protocol):
    """Where the edge serves a library CMRT and a job (the URLs an answer names)."""

    def cmrt(self, cmrt_id: str) -> str:
        """The URL of library CMRT `cmrt_id`."""
        ...

    def job(self, job_id: str) -> str:
        """The URL of job `job_id`."""
        ...


@dataclass(frozen=True)
class MotionFile:
    """A job's motion as a file: its text and the name to save it under."""

    text: str
    filename: str


# ---- the pool ---------------------------------------------------------------------------------
class SimulationBusyError(Busy):
    """Every pool process is busy and the waiting line is full (HTTP 503 with Retry-After);
    `what` names the request (`simulations`, `verify`)."""

    def __init__(self, what: str = "simulations") -> None:
        super().__init__(f"{what}: every simulation process is busy; retry later",
                         retry_after=RETRY_AFTER_S)


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

    async def call(self, fn: Any, *args: Any, what: str = "simulations") -> dict[str, Any]:
        """`fn(*args)` (a picklable clip body answering `{"status": ...}`) in the pool, bounded
        as the module docstring says (SimulationBusyError naming `what`)."""
        with self._admitted(what):
            task = self._get().submit(fn, *args)
            try:
                return await asyncio.wrap_future(task.future)
            except (TimeLimitError, WorkerDiedError) as err:
                return self._failure(err)

    def call_sync(self, fn: Any, *args: Any, what: str = "simulations") -> dict[str, Any]:
        """`call` for a caller on a worker thread (a use case that simulates as it decides):
        the same bounds, waiting on this thread."""
        with self._admitted(what):
            task = self._get().submit(fn, *args)
            try:
                return task.future.result()
            except (TimeLimitError, WorkerDiedError) as err:
                return self._failure(err)

    def simulate(self, spec_data: dict[str, Any], params: list[float]) -> dict[str, Any]:
        """One clip's outcome without traces, waiting on this thread (`call_sync`): a library
        answer's verification (busy: "verify: ...")."""
        return self.call_sync(run_clip, spec_data, params, False, False, what="verify")

    @contextlib.contextmanager
    def _admitted(self, what: str) -> Iterator[None]:
        with self._lock:
            if self._in_flight >= self.workers + MAX_WAITING:
                raise SimulationBusyError(what)
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


# ---- the use cases ----------------------------------------------------------------------------
def chosen_cmrt(repo: Repository, links: Links, spec: TaskSpec, choice: CmrtChoice | None
                ) -> tuple[list[float] | None, dict[str, Any] | None]:
    """The CMRT's parameter vector for `spec`, and how it was chosen (None, None: no CMRT);
    InvalidRequest naming `cmrt.id` or `cmrt.params` when it cannot be used."""
    if choice is None:
        return None, None
    if isinstance(choice, LibraryCmrtRef):
        try:
            rec = repo.get_cmrt(choice.id)
        except NotFound:
            raise InvalidRequest(f"cmrt.id: no library CMRT {choice.id!r}") from None
        params, about = rec.params, {"source": "library", "id": rec.id,
                                     "url": links.cmrt(rec.id)}
    elif isinstance(choice, JobBestCmrt):
        try:
            job = repo.get_job(choice.id)
        except NotFound:
            raise InvalidRequest(f"cmrt.id: no job {choice.id!r}") from None
        if job.best_params is None:
            raise InvalidRequest(f"cmrt.id: job {choice.id!r} has no best candidate yet "
                                 f"({job.status})")
        params, about = job.best_params, {"source": "job", "id": job.id,
                                          "url": links.job(job.id),
                                          "job_objective": job.best_objective}
    else:
        params, about = choice.params, {"source": "params"}
    try:
        checked = check_params(spec, params)
    except ParamsError as err:
        raise InvalidRequest(f"cmrt.{err}") from None
    about["params"] = [float(v) for v in checked]
    return about["params"], about


async def simulate(repo: Repository, pool: SimulationPool, links: Links,
                   req: SimulationRequest) -> dict[str, Any]:
    """One what-if clip: its outcome (`status` "done" or "failed" with `error`) and `cmrt`,
    how the CMRT was chosen (None: no anticipation)."""
    params, about = chosen_cmrt(repo, links, req.spec, req.cmrt)
    out = await pool.run(req.spec.model_dump(mode="json"), params, traces=req.traces,
                         frames=req.frames)
    out["cmrt"] = about
    log.info("simulation %s (%s, CMRT %s): %s in %.2f s CPU", req.spec.name, req.spec.task_type,
             about["source"] if about else "none", out["status"], out.get("cpu_seconds") or 0.0)
    return out


async def _simulated(pool: SimulationPool, what: str, failed: type[ApplicationError], fn: Any,
                     *args: Any) -> dict[str, Any]:
    """`fn(*args)` in the simulation pool: its `done` answer, or `failed` naming `what` failed
    and why (SimulationBusyError when every process is busy)."""
    out = await pool.call(fn, *args)
    if out["status"] != "done":
        raise failed(f"{what}: the simulation failed ({out['error']})")
    return out


async def _replay(pool: SimulationPool, spec_data: dict[str, Any], params: list[float] | None,
                  about: dict[str, Any] | None, compare: bool,
                  failed: type[ApplicationError]) -> dict[str, Any]:
    out = await _simulated(pool, "replay", failed, run_replay, spec_data, params, about,
                           compare)
    return out["replay"]


def _stored(load: Callable[[], TaskSpec], document: dict[str, Any], params: Any, what: str
            ) -> tuple[dict[str, Any], list[float]]:
    """A stored spec (its typed form from `load`) and parameter vector, checked
    (RequestConflict when they no longer fit); the stored document (the canonical dump of the
    spec) goes to the simulation pool as it is."""
    try:
        checked = check_params(load(), params)
    except (SpecError, ParamsError) as err:
        raise RequestConflict(f"{what}: cannot be replayed ({err})") from None
    return document, [float(v) for v in checked]


async def replay_cmrt(repo: Repository, pool: SimulationPool, links: Links, cmrt_id: str,
                      compare: bool) -> dict[str, Any]:
    """The replay document of library CMRT `cmrt_id` on its own task (its stored spec);
    NotFound, RequestConflict when it was stored without its spec or no longer fits it."""
    rec = repo.get_cmrt(cmrt_id)
    if rec.spec is None:
        raise RequestConflict(f"cmrt {cmrt_id!r}: stored without its task spec; it cannot be "
                              "replayed on its own task")
    what = f"cmrt {cmrt_id!r}"
    spec, params = _stored(lambda: parse_spec(rec.spec, what), rec.spec, rec.params, what)
    about = {"source": "library", "id": rec.id, "objective": rec.objective,
             "url": links.cmrt(rec.id)}
    return await _replay(pool, spec, params, about, compare, RequestConflict)


async def replay_job(repo: Repository, pool: SimulationPool, links: Links, job_id: str,
                     compare: bool) -> dict[str, Any]:
    """The replay document of job `job_id`'s best candidate so far on the job's spec;
    NotFound, RequestConflict while the job has no candidate yet."""
    job = repo.get_job(job_id)
    if job.best_params is None:
        raise RequestConflict(f"job {job_id!r}: no best candidate yet ({job.status})")
    # the job's spec by its hash: parsed once per process, not at every replay
    spec, params = _stored(lambda: stored_job_spec(job).spec, job.spec, job.best_params,
                           f"job {job_id!r}")
    about = {"source": "job", "id": job.id, "job_status": job.status,
             "job_objective": job.best_objective, "url": links.job(job.id)}
    return await _replay(pool, spec, params, about, compare, RequestConflict)


async def replay_whatif(repo: Repository, pool: SimulationPool, links: Links,
                        req: ReplayRequest) -> dict[str, Any]:
    """The replay document of a what-if clip; a clip that fails is an InvalidRequest naming
    the reason."""
    params, about = chosen_cmrt(repo, links, req.spec, req.cmrt)
    return await _replay(pool, req.spec.model_dump(mode="json"), params, about, req.compare,
                         InvalidRequest)


async def job_motion(repo: Repository, pool: SimulationPool, job_id: str,
                     fmt: Literal["bvh", "csv"], fps: float) -> MotionFile:
    """Job `job_id`'s best candidate so far simulated on its spec, written as `fmt` at `fps`
    (`sim.export`); Missing while the job has no candidate (there is no motion yet)."""
    job = repo.get_job(job_id)
    if job.best_params is None:
        raise Missing(f"job {job_id!r}: no best candidate yet ({job.status}); its motion "
                      "exists once a candidate has been evaluated")
    spec, params = _stored(lambda: stored_job_spec(job).spec, job.spec, job.best_params,
                           f"job {job_id!r}")
    out = await _simulated(pool, "motion", RequestConflict, run_export, spec, params, fmt, fps)
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", str(job.name or "job"))[:64]
    return MotionFile(out["text"], f"{name}-{job.id}.{fmt}")


__all__ = ["DEFAULT_FPS", "MAX_CMRT_PARAMS", "MAX_FPS", "MAX_WAITING", "MIN_FPS",
           "RETRY_AFTER_S", "CmrtChoice", "InlineCmrt", "JobBestCmrt", "LibraryCmrtRef", "Links",
           "MotionFile", "ReplayRequest", "SimulationBusyError", "SimulationPool",
           "SimulationRequest", "chosen_cmrt", "job_motion", "replay_cmrt", "replay_job",
           "replay_whatif", "simulate"]
