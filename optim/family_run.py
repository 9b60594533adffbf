"""Run a family in this process over one shared pool of workers: the command line's driver
of the family state machine (`optim.family.machine.next_actions` decides, this module carries
the actions out in threads and files; `worker.family` is the service's driver of the same).

`run_family(fs, executor, state_dir, resume=...)`:
  * every run of the plan is an ordinary `optim.run.optimize` (or, for the probes, one batch
    of evaluations) in a thread of this process; all of them evaluate their candidates through
    the ONE `executor` (a process pool of W workers), whose queue they share, so the workers
    stay busy while a run waits at its generation barrier. At most `max_active` runs are
    active (default: W + 1, at most the per-process simulator cache, so every worker keeps
    the active runs' simulators built); a run starts as soon as its needs are finished
    (`optim.family.plan.ready_runs`, critical path first). Once every run is finished the
    family's document is the outcome's `report` (`optim.family.report.family_report`).
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
value, whatever the run's rules: `optim.family.spec.member_objective`).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from optim._io import atomic_write_text
from optim.errors import CheckpointError, EvaluationError
from optim.executors import Executor
from optim.family import machine
from optim.family.plan import PROBES, PlannedRun, RunStart, plan_runs
from optim.family.report import family_report
from optim.family.spec import FamilySpec, member_objective, member_spec, parse_family
from optim.objective import SIMULATOR_CACHE_SIZE
from optim.outcome import EvalOutcome
from optim.result import OptimizationResult
from optim.run import CANCELLED, optimize

Log = Callable[[str], None]
STATE_FILE = "family.json"
PROBES_FILE = "probes.json"


@dataclass
class FamilyOutcome:
    """What a finished family run returns: every run's result, the probes, the family's
    document (`optim.family.report.family_report`) and its costs."""

    results: dict[str, OptimizationResult]
    probes: dict[float, EvalOutcome]
    wall_seconds: float
    max_concurrent: int = 0
    started: list[str] = field(default_factory=list)  # runs started in this process, in order
    report: dict[str, Any] = field(default_factory=dict)


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
    state_dir: Path, runs: list[PlannedRun]
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
    fs: FamilySpec, runs: list[PlannedRun], results: dict[str, OptimizationResult],
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


class _Runner:
    """Carries a family's actions out in threads of this process: each run an `optimize`
    over the shared executor, saved to state_dir as it finishes; the probes one batch per
    value. Its state: the finished runs, the probes, the future of each run under way
    (`active`: run id, PROBES for the probes) and the runs that ended without a result."""

    def __init__(self, fs: FamilySpec, executor: Executor, state_dir: Path,
                 say: Log, threads: cf.ThreadPoolExecutor,
                 outcome: FamilyOutcome, probes: dict[float, EvalOutcome] | None) -> None:
        self.fs, self.executor, self.state_dir = fs, executor, state_dir
        self.say, self.threads = say, threads
        self.outcome, self.probes = outcome, probes
        self.stop = threading.Event()
        self.active: dict[cf.Future, str] = {}
        self.failed: dict[str, str] = {}

    def state(self, capacity: int) -> machine.FamilyState:
        under_way = set(self.active.values())
        return machine.FamilyState(self.outcome.results, frozenset(under_way - {PROBES}),
                                   self.probes, PROBES in under_way, self.failed,
                                   capacity=capacity)

    def optimise(self, run: PlannedRun, st: RunStart) -> OptimizationResult | None:
        assert run.value is not None
        res = optimize(st.spec, self.executor, seed=self.fs.seed, x0=st.x0, basis=st.basis,
                       checkpoint=self.state_dir / f"{run.id}.ckpt", resume=True,
                       progress=lambda _s: self.stop.is_set(),
                       objective=member_objective(self.fs, run.value))
        if res.stop_rule == CANCELLED:
            return None  # its checkpoint holds the generations made; the next resume goes on
        res.save(self.state_dir / f"{run.id}.json")
        (self.state_dir / f"{run.id}.ckpt").unlink(missing_ok=True)
        return res

    def evaluate_probes(self, points: Sequence[tuple[float, Any]]) -> dict[float, EvalOutcome]:
        # one batch per value's objective, all submitted before waiting: the pool stays full
        with cf.ThreadPoolExecutor(max(1, len(points))) as tp:
            futs = [tp.submit(self.executor.map, member_objective(self.fs, v), [p])
                    for v, p in points]
            outs = [f.result()[0] for f in futs]
        got = {v: o for (v, _), o in zip(points, outs, strict=True)}
        atomic_write_text(self.state_dir / PROBES_FILE, json.dumps(
            {"outcomes": [[v, o.to_dict()] for v, o in sorted(got.items())]}) + "\n")
        return got

    def carry_out(self, action: machine.Action) -> dict[str, Any] | None:
        """Start a run or the probes; the family's document once it is finished."""
        if isinstance(action, machine.Finish):
            return family_report(self.fs, self.outcome.results, self.probes)
        if isinstance(action, machine.Fail):
            raise EvaluationError(f"run {action.run_id} {action.reason}")
        if isinstance(action, machine.EvaluateProbes):
            self.say(f"start {PROBES}")
            fut, rid = self.threads.submit(self.evaluate_probes, action.points), PROBES
        elif isinstance(action, machine.StartRun):
            rid = action.run.id
            self.say(f"start {rid}" + (f" (from {action.run.warm_from})"
                                       if action.run.warm_from else ""))
            fut = self.threads.submit(self.optimise, action.run, action.start)
        else:  # Cancel: never asked here (a kill stops the command, --resume goes on)
            raise AssertionError(f"unexpected {action!r}")
        self.active[fut] = rid
        self.outcome.started.append(rid)
        return None

    def collect(self) -> None:
        """Wait for a run (or the probes) to end and record what it gave."""
        finished, _ = cf.wait(self.active, return_when=cf.FIRST_COMPLETED)
        for fut in finished:
            rid = self.active.pop(fut)
            value = fut.result()  # an error stops the family (run_family's finally)
            if value is None:
                self.failed[rid] = "stopped before finishing"
            elif rid == PROBES:
                self.probes = value
            else:
                self.outcome.results[rid] = value
                self.say(f"done  {rid}: {value.objective:.4f}, {value.evaluations} "
                         f"evaluations, {value.stop_rule}")

    def drive(self, runs: list[PlannedRun], capacity: int) -> dict[str, Any]:
        """Ask the state machine and carry its actions out until the family is finished."""
        while True:
            for action in machine.next_actions(self.fs, self.state(capacity), runs):
                report = self.carry_out(action)
                if report is not None:
                    return report
            self.outcome.max_concurrent = max(self.outcome.max_concurrent, len(self.active))
            if not self.active:  # cannot happen: a plan is a DAG whose runs all start
                raise EvaluationError("the family has nothing left to run")
            self.collect()


def run_family(
    fs: FamilySpec,
    executor: Executor,
    state_dir: Path | str,
    *,
    resume: bool = False,
    max_active: int | None = None,
    log: Log | None = None,
    reuse: list[Path] | None = None,
) -> FamilyOutcome:
    """Run every run of the family not finished yet (see module docstring)."""
    t0 = time.perf_counter()
    state_dir = Path(state_dir)
    say = log or (lambda _msg: None)
    found = finished_cold_runs([Path(p) for p in reuse or []])  # read before writing
    _check_state(fs, state_dir, resume)
    runs = plan_runs(fs)
    results, probes = load_finished(state_dir, runs)
    reuse_cold_runs(fs, runs, results, state_dir, found, say)
    cap = max_active or max(2, min(executor.workers + 1, SIMULATOR_CACHE_SIZE))
    outcome = FamilyOutcome(results, {}, 0.0)
    with cf.ThreadPoolExecutor(cap, thread_name_prefix="cmrt-family") as threads:
        runner = _Runner(fs, executor, state_dir, say, threads, outcome, probes)
        try:
            outcome.report = runner.drive(runs, cap)
        finally:
            runner.stop.set()  # active runs end after their generation in hand (checkpointed)
    outcome.probes = runner.probes or {}
    outcome.wall_seconds = time.perf_counter() - t0
    return outcome


__all__ = ["FamilyOutcome", "load_finished", "run_family"]
