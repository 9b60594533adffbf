"""Run a family (optim.family's plan) in this process over one shared pool of workers.

`run_family(fs, executor, state_dir, resume=...)`:
  * every run of the plan is an ordinary `optim.run.optimize` (or, for the probes, one batch
    of evaluations) in a thread of this process; all of them evaluate their candidates through
    the ONE `executor` (a process pool of W workers), whose queue they share, so the workers
    stay busy while a run waits at its generation barrier. At most `max_active` runs are
    active (default: W + 1, at most the per-process simulator cache, so every worker keeps
    the active runs' simulators built); a run starts as soon as its needs are finished
    (`optim.family.ready_runs`, critical path first).
  * state_dir holds `family.json` (the spec), a checkpoint per active run (after every
    generation) and a result JSON per finished run (`<run id>.json`, `probes.json`): a killed
    run resumes (`resume=True`) with every finished run reused and every active one continued
    from its last generation, and gives the same family as an uninterrupted run (every run is
    deterministic in its spec, seed, start and basis; evaluations are deterministic).
  * `reuse`: state folders of other families; a cold run of this plan (from the flat spline,
    main rules) whose exact spec and seed a finished cold run there has is the same
    computation, so its result is copied instead of run (logged).
  * each member's generations cut their certain last early (`optim.rankcut`), as every
    `optimize` does: the pool posts a bound to the one slot running that candidate, so the
    batches in flight of the other members never read it.
Objectives are `SimObjective` of the member's spec under the main rules (one simulator per
value, whatever the run's rules); `objective_for` replaces them (tests: synthetic ones).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from optim._io import atomic_write_text
from optim.errors import CheckpointError, EvaluationError
from optim.executors import Executor
from optim.family import (
    PROBES,
    FamilyRun,
    FamilySpec,
    family_members,
    member_spec,
    parse_family,
    plan_runs,
    probe_points,
    ready_runs,
    run_start,
)
from optim.objective import SIMULATOR_CACHE_SIZE, SimObjective
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult
from optim.run import CANCELLED, optimize

ObjectiveFor = Callable[[FamilySpec, float], Callable[..., Any]]
Log = Callable[[str], None]
STATE_FILE = "family.json"
PROBES_FILE = "probes.json"


def default_objective(fs: FamilySpec, value: float) -> SimObjective:
    """The simulation of the member at `value` (main rules: one simulator per value)."""
    return SimObjective(member_spec(fs, value))


@dataclass
class FamilyOutcome:
    """What a finished family run returns: every run's result, the probes, and its costs."""

    results: dict[str, OptimizationResult]
    probes: dict[float, EvalOutcome]
    wall_seconds: float
    max_concurrent: int = 0
    started: list[str] = field(default_factory=list)  # runs started in this process, in order


def _check_state(fs: FamilySpec, state_dir: Path, resume: bool) -> None:
    """Create state_dir, or check that its family is `fs` when resuming."""
    state = state_dir / STATE_FILE
    body = json.dumps(fs.to_dict(), sort_keys=True)
    if state.exists():
        if not resume:
            raise CheckpointError(f"{state_dir}: holds an earlier family run; pass resume "
                                  "to continue it, or delete it")
        if json.loads(state.read_text()) != json.loads(body):
            raise CheckpointError(f"{state_dir}: holds a different family (spec, values or "
                                  "settings differ); delete it or choose another output")
        return
    state_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(state, body + "\n")


def load_finished(
    state_dir: Path, runs: list[FamilyRun]
) -> tuple[dict[str, OptimizationResult], dict[float, EvalOutcome] | None]:
    """The finished runs saved in state_dir, and the probes if they were evaluated."""
    results = {}
    for r in runs:
        p = state_dir / f"{r.id}.json"
        if r.kind != PROBES and p.exists():
            results[r.id] = OptimizationResult.load(p)
    probes = None
    pp = state_dir / PROBES_FILE
    if pp.exists():
        probes = {float(v): EvalOutcome.from_dict(o)
                  for v, o in json.loads(pp.read_text())["outcomes"]}
    return results, probes


def finished_cold_runs(others: list[Path]) -> list[OptimizationResult]:
    """The finished cold runs (flat spline, main rules) of other families' state folders."""
    found: list[OptimizationResult] = []
    for other in others:
        try:
            ofs = parse_family(json.loads((Path(other) / STATE_FILE).read_text()),
                               f"{other}/{STATE_FILE}")
        except OSError as err:
            raise CheckpointError(f"{other}: not a family run folder ({err.strerror})") from None
        oruns = plan_runs(ofs)
        done, _ = load_finished(Path(other), oruns)
        found += [done[r.id] for r in oruns if r.cold and r.id in done]
    return found


def reuse_cold_runs(
    fs: FamilySpec, runs: list[FamilyRun], results: dict[str, OptimizationResult],
    state_dir: Path, found: list[OptimizationResult], log: Log,
) -> None:
    """Copy into state_dir each of `found` that is the same computation as a cold run of this
    plan not finished yet (the same spec, rules included, and the same seed)."""
    for r in runs:
        if not r.cold or r.id in results:
            continue
        assert r.value is not None
        want = member_spec(fs, r.value).model_dump(mode="json")
        for res in found:
            if res.spec == want and res.seed == fs.seed and res.basis_id is None:
                res.save(state_dir / f"{r.id}.json")
                results[r.id] = res
                log(f"reuse {r.id}: {res.objective:.4f}, {res.evaluations} evaluations")
                break


def run_family(
    fs: FamilySpec,
    executor: Executor,
    state_dir: Path | str,
    *,
    resume: bool = False,
    max_active: int | None = None,
    objective_for: ObjectiveFor = default_objective,
    log: Log | None = None,
    reuse: list[Path] | None = None,
) -> FamilyOutcome:
    """Run every run of the family not finished yet (see module docstring)."""
    t0 = time.perf_counter()
    state_dir = Path(state_dir)
    found = finished_cold_runs([Path(p) for p in reuse or []])  # read before writing
    _check_state(fs, state_dir, resume)
    runs = plan_runs(fs)
    results, probes = load_finished(state_dir, runs)
    reuse_cold_runs(fs, runs, results, state_dir, found, log or (lambda _msg: None))
    done = set(results) | ({PROBES} if probes is not None else set())
    cap = max_active or max(2, min(executor.workers + 1, SIMULATOR_CACHE_SIZE))
    stop = threading.Event()
    lock = threading.Lock()
    say = log or (lambda _msg: None)

    def optimise(run: FamilyRun) -> OptimizationResult | None:
        with lock:  # a consistent view of the finished runs
            snapshot = dict(results)
        st = run_start(fs, run, runs, snapshot)
        assert run.value is not None
        res = optimize(st.spec, executor, seed=fs.seed, x0=st.x0, basis=st.basis,
                       checkpoint=state_dir / f"{run.id}.ckpt", resume=True,
                       progress=lambda _s: stop.is_set(),
                       objective=objective_for(fs, run.value))
        if res.stop_rule == CANCELLED:
            return None  # its checkpoint holds the generations made; the next resume goes on
        res.save(state_dir / f"{run.id}.json")
        (state_dir / f"{run.id}.ckpt").unlink(missing_ok=True)
        return res

    def evaluate_probes() -> dict[float, EvalOutcome]:
        with lock:
            snapshot = dict(results)
        members = {v: res for v, (_, res) in family_members(runs, snapshot).items()}
        points = probe_points(fs, members)
        outs: list[EvalOutcome] = []
        # one batch per value's objective, all submitted before waiting: the pool stays full
        with cf.ThreadPoolExecutor(max(1, len(points))) as tp:
            futs = [tp.submit(executor.map, objective_for(fs, v), [p]) for v, p, _, _ in points]
            outs = [f.result()[0] for f in futs]
        got = {v: o for (v, _, _, _), o in zip(points, outs, strict=True)}
        atomic_write_text(state_dir / PROBES_FILE, json.dumps(
            {"outcomes": [[v, o.to_dict()] for v, o in sorted(got.items())]}) + "\n")
        return got

    outcome = FamilyOutcome(results, probes or {}, 0.0)
    active: dict[cf.Future, FamilyRun] = {}
    with cf.ThreadPoolExecutor(cap, thread_name_prefix="cmrt-family") as threads:
        try:
            while True:
                for run in ready_runs(runs, done, {r.id for r in active.values()}):
                    if len(active) >= cap:
                        break
                    say(f"start {run.id}" + (f" (from {run.warm_from})" if run.warm_from
                                             else ""))
                    fut = threads.submit(evaluate_probes if run.kind == PROBES else optimise,
                                         *(() if run.kind == PROBES else (run,)))
                    active[fut] = run
                    outcome.started.append(run.id)
                outcome.max_concurrent = max(outcome.max_concurrent, len(active))
                if not active:
                    break
                finished, _ = cf.wait(active, return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    run = active.pop(fut)
                    value = fut.result()  # an error stops the family (finally: see below)
                    if value is None:
                        raise EvaluationError(f"run {run.id} stopped before finishing")
                    with lock:
                        if run.kind == PROBES:
                            outcome.probes = value
                        else:
                            results[run.id] = value
                            say(f"done  {run.id}: {value.objective:.4f}, "
                                f"{value.evaluations} evaluations, {value.stop_rule}")
                        done.add(run.id)
        finally:
            stop.set()  # active runs end after their generation in hand (checkpointed)
    outcome.wall_seconds = time.perf_counter() - t0
    return outcome


__all__ = ["FamilyOutcome", "default_objective", "load_finished", "run_family"]
