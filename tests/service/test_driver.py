"""Job driver over the store, with a synthetic objective (unit tests)."""

from __future__ import annotations

import threading

import pytest
from local_pool import local_executor
from svc_helpers import bend_spec
from synthetic import Sphere

from optim.executors import EvalOutcome, SerialExecutor
from sim.spec import parse_spec
from store import NotFound
from store.records import CANCELLED, FAILED, STOPPED, JobStart
from worker.driver import FINAL_GENERATION, CancelFlags, JobDriver


def _job(repo, spec=None, seed=1):
    spec = parse_spec(spec or bend_spec())
    return repo.create_job(spec.model_dump(mode="json"), name=spec.name, family=spec.family_name,
                           task=spec.task_type, seed=seed)


def test_job_runs_to_its_stop_rule_and_lands_in_library(repo, config, local_executor):
    job = _job(repo)
    status = JobDriver(repo, job.id, local_executor, config).run()
    assert status == STOPPED
    j = repo.get_job(job.id)
    assert j.stop_rule == "max_evaluations" and j.iterations == 3 and j.evaluations == 12
    gens = repo.generations(job.id)
    assert [g.iteration for g in gens] == [0, 1, 2]
    for g in range(3):
        c = repo.evaluation_counts(job.id, g)
        assert (c.done, c.pending, c.failed) == (4, 0, 0)
    assert repo.evaluation_counts(job.id, FINAL_GENERATION).done == 2
    items, total = repo.list_cmrts("bend")
    assert total == 1 and items[0].job_id == job.id
    assert items[0].task_parameters == {"duration": 0.3}
    assert items[0].objective == pytest.approx(j.best_objective)


def test_resume_from_stored_generation_gives_the_same_result(repo, config, local_executor):
    ref = _job(repo)
    JobDriver(repo, ref.id, local_executor, config).run()

    job = _job(repo)
    stop = threading.Event()
    d = JobDriver(repo, job.id, local_executor, config, shutdown=stop,
                  on_generation=lambda g: stop.set() if g == 0 else None)
    assert d.run() is None  # interrupted after generation 0, job still running
    assert repo.get_job(job.id).status == "running" and repo.get_job(job.id).iterations == 1
    # a half-done generation 1 from the dead driver: its done rows must be reused, not redone
    assert JobDriver(repo, job.id, local_executor, config).run() == STOPPED
    a, b = repo.get_job(ref.id), repo.get_job(job.id)
    assert a.best_objective == b.best_objective and a.best_params == b.best_params
    assert [g.best for g in repo.generations(ref.id)] == [g.best for g in repo.generations(job.id)]


def test_half_done_generation_is_not_evaluated_again(repo, config):
    calls = []

    class Counting(Sphere):
        def __call__(self, x):
            calls.append(tuple(x))
            return super().__call__(x)

    ex = local_executor(config, SerialExecutor(), lambda s: Counting())
    job = _job(repo)
    stop = threading.Event()
    JobDriver(repo, job.id, ex, config, shutdown=stop,
              on_generation=lambda g: stop.set()).run()
    # simulate a crash in generation 1 after 2 of 4 candidates were stored
    from optim.cmaes import CmaOptimizer
    opt = CmaOptimizer.loads(repo.latest_generation(job.id).optimizer_state)
    xs = opt.ask()
    repo.put_pending_evaluations(job.id, 1, [list(x) for x in xs])
    for i in (0, 1):
        repo.store_result(job.id, 1, i, objective=0.5, fell=False, cpu_seconds=0.0)
    calls.clear()
    assert JobDriver(repo, job.id, ex, config).run() == STOPPED
    rows = repo.evaluations(job.id, 1)
    assert [r.objective for r in rows[:2]] == [0.5, 0.5]
    assert len(calls) == 2 + 4 + 2  # rest of gen 1, gen 2, final pair
    assert all(r.attempts == 1 for g in (1, 2) for r in repo.evaluations(job.id, g))


def test_cancel_between_generations(repo, config, local_executor):
    job = _job(repo, bend_spec(max_evaluations=400))
    d = JobDriver(repo, job.id, local_executor, config,
                  on_generation=lambda g: repo.request_cancel(job.id) if g == 1 else None)
    assert d.run() == CANCELLED
    j = repo.get_job(job.id)
    assert j.status == CANCELLED and j.iterations == 2
    assert repo.list_cmrts("bend")[1] == 0


class _Killer:
    def __call__(self, x):
        raise SystemExit  # stand-in for a process death inside the pool


class _DyingPool(SerialExecutor):
    """A pool whose process dies whenever candidate x[0] > 0.5 (EvaluationError like optim's)."""

    def __init__(self):
        self.maps = 0

    def map(self, fn, batch, cut_margin=None):
        from optim.errors import EvaluationError

        self.maps += 1
        if any(x[0] > 0.5 for x in batch):
            raise EvaluationError("a worker process died")
        return [EvalOutcome(objective=float(sum(x))) for x in batch]


def test_candidate_killing_its_pool_process_fails_job_after_max_attempts(repo, config):
    pool = _DyingPool()
    ex = local_executor(config, pool)
    spec = bend_spec()
    spec["optimize"]["sigma0"] = 0.9
    job = _job(repo, spec, seed=3)
    assert JobDriver(repo, job.id, ex, config).run() == FAILED
    j = repo.get_job(job.id)
    assert "worker process died every time" in j.error and "started 2 times" in j.error
    assert pool.maps <= config.max_attempts + 1


def test_lease_held_elsewhere_means_no_second_driver(repo, config, local_executor):
    job = _job(repo)
    assert repo.acquire_driver_lease(job.id, "other", 60)
    assert JobDriver(repo, job.id, local_executor, config).run() is None
    assert repo.get_job(job.id).status == "queued"


@pytest.mark.parametrize(("duration", "winner"), [(0.3, "flat"), (0.4, "search")])
def test_library_entry_is_never_worse_than_the_flat_spline(repo, config, duration, winner):
    """Issue 11's case on real physics: a bend job stopped by its cap (popsize 4,
    max_evaluations 8). At T = 0.3 s (seed 0) the best of 8 candidates is worse than no
    anticipation, so the entry is the flat spline; at T = 0.4 s the search wins."""
    from optim.spline import flat_params

    spec = bend_spec(duration=duration, popsize=4, max_evaluations=8)
    spec["clip"] = {"preparation": 0.5, "duration": duration, "decay": 0.6}
    spec["task"] = {"type": "pose_change",
                    "target": {"waist": -90, "shoulder_r": 90, "shoulder_l": 90}}
    job = _job(repo, spec, seed=0)
    ex = local_executor(config, SerialExecutor())  # the real simulation objective
    assert JobDriver(repo, job.id, ex, config).run() == STOPPED
    entry = repo.job_cmrt(job.id)
    best, flat = repo.evaluations(job.id, FINAL_GENERATION)[::-1]  # index 0 flat, 1 best
    assert entry.winner == winner
    assert entry.objective_without == flat.objective
    assert entry.objective == min(best.objective, flat.objective) <= entry.objective_without
    if winner == "flat":
        assert best.objective > flat.objective
        assert entry.params == pytest.approx(list(flat_params(parse_spec(spec))))
    else:
        assert entry.params == pytest.approx(best.params)


def test_take_over_after_a_lease_expiry_is_logged_at_info(repo, config, local_executor, caplog):
    import logging
    import time

    from optim.loop import SearchSpace, new_optimizer

    job = _job(repo)
    spec = parse_spec(bend_spec())
    xs = new_optimizer(spec, SearchSpace.of(spec), 1).ask()  # what the dead driver asked
    repo.set_job_status(job.id, "running")
    assert repo.acquire_driver_lease(job.id, "host:1:dead", 0.05)
    repo.put_pending_evaluations(job.id, 0, [list(x) for x in xs])
    repo.claim_evaluation(job.id, 0, 0)
    repo.store_result(job.id, 0, 0, objective=1.0, fell=False, cpu_seconds=0.0)
    repo.claim_evaluation(job.id, 0, 2)  # started, then its driver died
    time.sleep(0.1)  # the lease expires
    with caplog.at_level(logging.INFO, logger="worker.driver"):
        assert JobDriver(repo, job.id, local_executor, config).run() == STOPPED
    msgs = [r.getMessage() for r in caplog.records if "taking over" in r.getMessage()]
    assert len(msgs) == 1 and msgs[0].startswith(f"job {job.id}: taking over from driver "
                                                 "host:1:dead whose lease expired")
    assert ("resuming at generation 0: 1 of its 4 candidates already evaluated, 1 started and "
            "not finished, run again: [2]") in msgs[0]


def test_job_result_equals_the_command_lines_search_from_the_same_start(repo, config,
                                                                        local_executor):
    """A job started at x0 keeps where it started, and its result document is what
    `optim.run.optimize` gives for the same spec, seed and start (wall time aside)."""
    from optim.run import optimize
    from optim.spline import flat_params

    spec = parse_spec(bend_spec())
    x0 = [min(1.0, v + 0.05) for v in flat_params(spec)]
    start = JobStart("a test", tuple(x0))
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=3, start=start)
    assert JobDriver(repo, job.id, local_executor, config).run() == STOPPED
    assert repo.get_job(job.id).start == start
    got = repo.job_result(job.id)
    want = optimize(spec, SerialExecutor(), seed=3, x0=x0, objective=Sphere(centre=0.3),
                    cut=False).to_dict()
    for key in ("params", "objective", "baseline_objective", "evaluations", "iterations",
                "stop_rule", "history", "knot_times", "values"):
        assert got[key] == want[key], key
    assert len(got["history"]) == 3 and got["objective"] < got["baseline_objective"]


def test_the_rank_cut_keeps_a_local_pool_job_identical(repo, config):
    """The embedded path cuts a generation's certain last candidate (optim.rankcut) in its
    real process pool, and the job's every generation (candidates, best, median, sigma), its
    stop rule and its result are those of the command line's run without any cut."""
    from synthetic import RunningSum

    from optim.run import optimize
    from sim import load_spec
    from worker.fairpool import FairPool

    spec = load_spec("examples/fast_bend.yaml")
    spec = spec.model_copy(update={"optimize": spec.optimize.model_copy(
        update={"threshold": None, "max_evaluations": 150, "min_evaluations": 0,
                "window": 5})})
    # worse candidates run longer: the last one left in a generation is often the worst
    fn = RunningSum(steps=200, check_every=20, sleep=1e-3)
    ref = optimize(spec, SerialExecutor(), seed=3, objective=fn, cut=False)
    ex = local_executor(config, FairPool(2), lambda s: fn)
    try:
        job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                              family=spec.family_name, task=spec.task_type, seed=3)
        JobDriver(repo, job.id, ex, config).run()
    finally:
        ex.close()
    gens = repo.generations(job.id)
    rows = [r for g in gens for r in repo.evaluations(job.id, g.iteration)]
    assert sum(bool((r.details or {}).get("cut")) for r in rows) >= 1  # the cut happened
    assert len(gens) == len(ref.history) >= 10
    for g, h in zip(gens, ref.history, strict=True):
        assert (g.best, g.median, g.sigma, g.best_so_far, g.evaluations) == (
            h["best"], h["median"], h["sigma"], h["best_so_far"], h["evaluations"])
        assert g.worst <= h["worst"]  # a lower bound where the last was cut
    got, want = repo.job_result(job.id), ref.to_dict()
    for d in (got, want):
        d.pop("wall_seconds")
        d["history"] = [{k: v for k, v in h.items() if k != "worst"} for h in d["history"]]
    assert got == want


def test_a_process_reads_its_jobs_cancel_flags_together(repo, monkeypatch):
    a, b = _job(repo, seed=1), _job(repo, seed=2)
    reads: list[list[str]] = []
    read = repo.cancel_flags
    monkeypatch.setattr(repo, "cancel_flags", lambda ids: reads.append(sorted(ids)) or read(ids))
    flags = CancelFlags(repo, interval=60.0)
    flags.watch(a.id)
    flags.watch(b.id)
    assert flags.requested(a.id) is False and flags.requested(b.id) is False
    assert reads == [sorted([a.id, b.id])]  # one read for both jobs
    repo.request_cancel(b.id)
    assert flags.requested(b.id) is False  # as read, until the next tick
    flags.interval = 0.0
    assert flags.requested(b.id) is True and len(reads) == 2
    flags.unwatch(a.id)
    assert flags.requested(b.id) is True and reads[-1] == [b.id]
    with pytest.raises(NotFound):
        flags.requested("no-such-job")
