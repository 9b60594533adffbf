"""Contract: generations (checkpointing the optimizer) and evaluations (first result wins,
attempt counting, exact counts under concurrency)."""

from __future__ import annotations

import multiprocessing as mp
import pickle
import random
import threading

import numpy as np
import pytest
from store_helpers import get_evaluation, get_optimizer_state

from store.db import make_engine
from store.errors import NotFound
from store.records import GenerationCounts
from store.repository import SqlRepository

SPEC = {"name": "push", "task": "push"}


def new_job(repo: SqlRepository):
    job = repo.create_job(SPEC, name="push", family="push", task="push", seed=7, workers=2)
    repo.set_job_status(job.id, "running")
    return job


def figures(best: float, evaluations: int, **kw):
    fig = dict(
        best=best, median=best + 1, worst=best + 2, sigma=0.2, best_so_far=best,
        evaluations=evaluations, wall_time=1.5, candidates=[[0.1, 0.2], [0.3, 0.4]],
        optimizer_state=pickle.dumps({"evaluations": evaluations}),
    )  # fmt: skip
    fig.update(kw)
    return fig


# ---- generations -------------------------------------------------------------------------
def test_record_generation_updates_the_job(repo: SqlRepository) -> None:
    job = new_job(repo)
    assert repo.latest_generation(job.id) is None and get_optimizer_state(repo, job.id) is None
    g0 = repo.record_generation(job.id, 0, **figures(5.0, 10, best_params=[0.1, 0.2]))
    assert (g0.iteration, g0.best, g0.evaluations) == (0, 5.0, 10)
    assert pickle.loads(g0.optimizer_state) == {"evaluations": 10}
    repo.record_generation(job.id, 1, **figures(3.0, 20, best_params=[0.3, 0.4]))
    repo.record_generation(job.id, 2, **figures(4.0, 30, best_params=[0.5, 0.6]))

    rec = repo.get_job(job.id)
    assert (rec.iterations, rec.evaluations) == (3, 30)
    assert rec.best_objective == 3.0 and rec.best_params == [0.3, 0.4]
    assert pickle.loads(get_optimizer_state(repo, job.id)) == {"evaluations": 30}
    latest = repo.latest_generation(job.id)
    assert latest.iteration == 2 and pickle.loads(latest.optimizer_state)["evaluations"] == 30
    assert latest.candidates == [[0.1, 0.2], [0.3, 0.4]]

    assert [g.iteration for g in repo.generations(job.id)] == [0, 1, 2]
    after = repo.generations(job.id, after=0)
    assert [g.iteration for g in after] == [1, 2] and all(g.optimizer_state is None for g in after)
    assert all(g.optimizer_state for g in repo.generations(job.id, with_state=True))


def test_record_generation_is_idempotent(repo: SqlRepository) -> None:
    job = new_job(repo)
    first = repo.record_generation(job.id, 0, **figures(5.0, 10))
    again = repo.record_generation(
        job.id, 0, **figures(1.0, 99, optimizer_state=b"other", best_params=[0.9])
    )
    assert again == first
    rec = repo.get_job(job.id)
    assert (rec.iterations, rec.evaluations, rec.best_objective) == (1, 10, 5.0)
    assert rec.best_params is None
    assert len(repo.generations(job.id)) == 1
    assert pickle.loads(get_optimizer_state(repo, job.id)) == {"evaluations": 10}


def test_late_older_generation_does_not_rewind_the_state(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.record_generation(job.id, 1, **figures(2.0, 20))
    repo.record_generation(job.id, 0, **figures(1.0, 10))
    rec = repo.get_job(job.id)
    assert rec.iterations == 2 and rec.evaluations == 20 and rec.best_objective == 1.0
    assert pickle.loads(get_optimizer_state(repo, job.id)) == {"evaluations": 20}
    assert repo.latest_generation(job.id).iteration == 1


def test_generation_accepts_numpy_and_refuses_nan(repo: SqlRepository) -> None:
    job = new_job(repo)
    cands = np.array([[0.25, 0.5], [0.75, 1.0]])
    g = repo.record_generation(
        job.id, 0, **figures(np.float64(2.5), np.int64(8), candidates=cands,
                             best_params=cands[0])
    )  # fmt: skip
    assert g.candidates == [[0.25, 0.5], [0.75, 1.0]] and g.best == 2.5
    assert repo.get_job(job.id).best_params == [0.25, 0.5]
    with pytest.raises(ValueError):
        repo.record_generation(job.id, 1, **figures(float("nan"), 16))
    with pytest.raises(ValueError):
        repo.record_generation(job.id, 1, **figures(1.0, 16, candidates=[[float("nan")]]))
    assert repo.get_job(job.id).iterations == 1


def test_generation_of_unknown_job(repo: SqlRepository) -> None:
    with pytest.raises(NotFound):
        repo.record_generation("nope", 0, **figures(1.0, 1))
    with pytest.raises(NotFound):
        repo.generations("nope")
    with pytest.raises(NotFound):
        repo.latest_generation("nope")


# ---- evaluations -------------------------------------------------------------------------
def test_pending_evaluations_are_idempotent(repo: SqlRepository) -> None:
    job = new_job(repo)
    params = [[0.1 * i, 0.2] for i in range(4)]
    assert repo.put_pending_evaluations(job.id, 0, params) == 4
    assert repo.put_pending_evaluations(job.id, 0, params) == 0
    evs = repo.evaluations(job.id, 0)
    assert [e.index for e in evs] == [0, 1, 2, 3]
    assert [e.params for e in evs] == params
    assert all(e.status == "pending" and e.attempts == 0 for e in evs)
    assert repo.evaluation_counts(job.id, 0) == GenerationCounts(pending=4)
    assert repo.evaluations(job.id, 1) == []
    with pytest.raises(NotFound):
        repo.put_pending_evaluations("nope", 0, params)


# ---- concurrency -------------------------------------------------------------------------
POP = 12
WRITERS = 3


# ---- the workers' per-candidate calls: claim_evaluation + store_result --------------------
def test_claim_counts_an_attempt_and_reports_the_job(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.5, 0.25], [0.6, 0.6]])
    claim = repo.claim_evaluation(job.id, 0, 0)
    assert (claim.job_id, claim.generation, claim.index) == (job.id, 0, 0)
    assert (claim.status, claim.attempts, claim.params) == ("pending", 1, [0.5, 0.25])
    assert claim.job_status == "running" and not claim.job_terminal
    assert repo.claim_evaluation(job.id, 0, 0).attempts == 2  # e.g. its worker died
    assert get_evaluation(repo, job.id, 0, 0).attempts == 2
    assert repo.store_result(job.id, 0, 0, objective=1.5, fell=False, cpu_seconds=0.25)
    # a re-delivered message for a finished candidate counts nothing and sees it done
    done = repo.claim_evaluation(job.id, 0, 0)
    assert (done.status, done.attempts) == ("done", 2)
    assert get_evaluation(repo, job.id, 0, 0).attempts == 2

    repo.set_job_status(job.id, "cancelled")
    late = repo.claim_evaluation(job.id, 0, 1)
    assert late.job_status == "cancelled" and late.job_terminal
    with pytest.raises(NotFound):
        repo.claim_evaluation(job.id, 0, 7)
    with pytest.raises(NotFound):
        repo.claim_evaluation(job.id, 1, 0)
    with pytest.raises(NotFound):
        repo.claim_evaluation("nope", 0, 0)


def test_store_result_first_result_wins(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.5, 0.5], [0.6, 0.6], [0.7, 0.7]])
    repo.claim_evaluation(job.id, 0, 0)
    assert repo.store_result(
        job.id, 0, 0, objective=1.25, fell=True, cpu_seconds=0.5, details={"worker": "w1"}
    )
    first = get_evaluation(repo, job.id, 0, 0)
    assert (first.status, first.objective, first.fell, first.cpu_seconds) == ("done", 1.25,
                                                                            True, 0.5)
    assert (first.attempts, first.params, first.details) == (1, [0.5, 0.5], {"worker": "w1"})
    assert first.error is None
    assert not repo.store_result(job.id, 0, 0, objective=9.0, fell=False, cpu_seconds=3.0)
    assert not repo.store_result(job.id, 0, 0, objective=None, fell=None, cpu_seconds=None,
                                 error="late failure")
    assert get_evaluation(repo, job.id, 0, 0) == first
    # an error makes it failed; a result never claimed still counts one attempt
    assert repo.store_result(job.id, 0, 1, objective=None, fell=None, cpu_seconds=None,
                             error="gave up")
    failed = get_evaluation(repo, job.id, 0, 1)
    assert (failed.status, failed.objective, failed.error, failed.attempts) == (
        "failed", None, "gave up", 1)
    assert repo.evaluation_counts(job.id, 0) == GenerationCounts(pending=1, done=1, failed=1)
    # numpy numbers are plain data; nothing is stored for refused input
    assert repo.store_result(job.id, 0, 2, objective=np.float64(0.5), fell=np.bool_(False),
                             cpu_seconds=np.float32(0.125), details={"x": np.arange(2)})
    assert get_evaluation(repo, job.id, 0, 2).details == {"x": [0, 1]}
    with pytest.raises(ValueError):
        repo.store_result(job.id, 0, 2, objective=float("nan"), fell=False, cpu_seconds=0)
    with pytest.raises(ValueError):
        repo.store_result(job.id, 0, 2, objective=None, fell=False, cpu_seconds=0)
    with pytest.raises(NotFound):
        repo.store_result(job.id, 0, 3, objective=1.0, fell=False, cpu_seconds=0)
    with pytest.raises(NotFound):
        repo.store_result("nope", 0, 0, objective=1.0, fell=False, cpu_seconds=0)
    assert repo.evaluations(job.id, 0)[2].objective == 0.5


def test_a_job_lists_the_fingerprints_that_evaluated_it(repo: SqlRepository) -> None:
    job = new_job(repo)
    assert repo.evaluation_fingerprints(job.id) == []
    repo.put_pending_evaluations(job.id, 0, [[0.1, 0.1], [0.2, 0.2], [0.3, 0.3], [0.4, 0.4]])
    for i, fp in enumerate(["b" * 16, "a" * 16, "b" * 16, None]):
        assert repo.store_result(job.id, 0, i, objective=1.0 + i, fell=False, cpu_seconds=0.1,
                                 fingerprint=fp)
    assert [e.fingerprint for e in repo.evaluations(job.id, 0)] == ["b" * 16, "a" * 16,
                                                                    "b" * 16, None]
    assert repo.evaluation_fingerprints(job.id) == ["a" * 16, "b" * 16]
    # a late duplicate from another worker changes nothing, its fingerprint included
    assert not repo.store_result(job.id, 0, 0, objective=9.0, fell=False, cpu_seconds=0.1,
                                 fingerprint="c" * 16)
    assert repo.evaluation_fingerprints(job.id) == ["a" * 16, "b" * 16]
    other = new_job(repo)
    assert repo.evaluation_fingerprints(other.id) == []
    with pytest.raises(NotFound):
        repo.evaluation_fingerprints("nope")


def test_claimed_attempts_are_bounded_by_the_caller(repo: SqlRepository) -> None:
    """The worker path of a candidate that kills its worker every time."""
    max_attempts = 3
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.1], [0.2]])
    for n in range(1, max_attempts + 1):
        claim = repo.claim_evaluation(job.id, 0, 1)
        assert claim.attempts == n and claim.status == "pending"  # ... and the worker dies
    claim = repo.claim_evaluation(job.id, 0, 1)
    assert claim.attempts > max_attempts
    out = repo.fail_evaluation(job.id, 0, 1, f"gave up after {max_attempts} attempts")
    assert out is True
    assert repo.evaluation_counts(job.id, 0) == GenerationCounts(pending=1, failed=1)
    assert repo.fail_evaluation(job.id, 0, 1, "again") is False
    again = repo.claim_evaluation(job.id, 0, 1)
    assert (again.status, again.attempts) == ("failed", claim.attempts)
    assert not repo.store_result(job.id, 0, 1, objective=1.0, fell=False, cpu_seconds=1.0)
    assert get_evaluation(repo, job.id, 0, 1).status == "failed"
    # the other candidate is unaffected
    assert repo.claim_evaluation(job.id, 0, 0).attempts == 1
    assert repo.store_result(job.id, 0, 0, objective=1.0, fell=False, cpu_seconds=1.0)


def test_evaluation_writes_leave_the_connection_settings_alone(db) -> None:
    """PostgreSQL: only the per-candidate transactions commit asynchronously (SET LOCAL), the
    pooled connection goes back with the server's setting."""
    url, _engine = db
    engine = make_engine(url, pool_size=1, max_overflow=0)  # one connection: the one used
    try:
        repo = SqlRepository(engine)
        job = new_job(repo)
        repo.put_pending_evaluations(job.id, 0, [[0.1]])
        repo.claim_evaluation(job.id, 0, 0)
        repo.store_result(job.id, 0, 0, objective=1.0, fell=False, cpu_seconds=0.0)
        with pytest.raises(NotFound):
            repo.store_result(job.id, 0, 1, objective=1.0, fell=False, cpu_seconds=0.0)
        assert get_evaluation(repo, job.id, 0, 0).status == "done"
        if engine.dialect.name == "postgresql":
            with engine.connect() as c:
                assert c.exec_driver_sql("SHOW synchronous_commit").scalar() == "on"
    finally:
        engine.dispose()


def test_evaluation_writes_commit_asynchronously_on_postgresql(db) -> None:
    """PostgreSQL: the per-candidate writes do not wait for a WAL flush each (see
    SqlRepository), the other writes do. Counted with the server's WAL sync counter.

    The counter is server-wide and PostgreSQL 15 reports each backend's share lazily (at most
    once a second, or after 10 s idle), so other sessions' syncs can land in any window: the
    writing backend (the only connection of its pool) is made to flush before every reading
    (`pg_stat_force_next_flush()`), and each phase is measured in several interleaved trials
    whose minimum is taken (others' syncs only ever add)."""
    url, engine0 = db
    if engine0.dialect.name != "postgresql":
        pytest.skip("PostgreSQL only")
    from sqlalchemy import text

    engine = make_engine(url, pool_size=1, max_overflow=0)  # one backend does every write
    try:
        repo = SqlRepository(engine)

        def wal_syncs() -> int:
            with engine.connect() as c:  # the writer's own backend: flush its pending stats
                c.execute(text("SELECT pg_stat_force_next_flush()"))
            with engine0.connect() as c:
                return int(c.execute(text("SELECT wal_sync FROM pg_stat_wal")).scalar())

        job = new_job(repo)
        n, trials = 40, 5
        repo.put_pending_evaluations(job.id, 0, [[0.5]] * (2 * n * trials))
        asynchronous, synchronous = [], []
        for k in range(trials):
            first = 2 * n * k
            before = wal_syncs()
            for i in range(first, first + n):
                repo.claim_evaluation(job.id, 0, i)
                repo.store_result(job.id, 0, i, objective=1.0, fell=False, cpu_seconds=0.0)
            asynchronous.append(wal_syncs() - before)
            before = wal_syncs()
            for i in range(first + n, first + 2 * n):  # a synchronous write each
                repo.put_pending_evaluations(job.id, 1000 + i, [[0.5]])
            synchronous.append(wal_syncs() - before)
    finally:
        engine.dispose()
    print(f"WAL syncs per {n} writes: per-candidate {asynchronous}, others {synchronous}")
    assert min(asynchronous) < n // 2 <= min(synchronous), (asynchronous, synchronous)


def _claim_and_store(repo: SqlRepository, job_id: str, seed: int) -> list[tuple[int, bool]]:
    """The worker path for every candidate of generation 0, in a shuffled order."""
    order = list(range(POP))
    random.Random(seed).shuffle(order)
    seen = []
    for i in order:
        claim = repo.claim_evaluation(job_id, 0, i)
        changed = repo.store_result(job_id, 0, i, objective=float(i), fell=False,
                                    cpu_seconds=float(seed), details={"writer": seed})
        seen.append((i, changed, claim.status))
    return seen


def _claim_child(url: str, job_id: str, seed: int, queue) -> None:
    engine = make_engine(url)
    try:
        queue.put((seed, _claim_and_store(SqlRepository(engine), job_id, seed)))
    finally:
        engine.dispose()


def test_concurrent_worker_writes_from_processes(repo: SqlRepository, db) -> None:
    url, _engine = db
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[i / POP] for i in range(POP)])
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_claim_child, args=(url, job.id, s, queue))
             for s in range(WRITERS)]
    for p in procs:
        p.start()
    runs = dict(queue.get(timeout=60) for _ in procs)
    for p in procs:
        p.join(30)
        assert p.exitcode == 0
    winners = {i: seed for seed, run in runs.items() for i, changed, _ in run if changed}
    assert sorted(winners) == list(range(POP)), "each candidate stored exactly once"
    assert sum(changed for run in runs.values() for _, changed, _ in run) == POP
    evs = repo.evaluations(job.id, 0)
    assert [e.status for e in evs] == ["done"] * POP
    # the stored result is the one whose write returned True
    assert [e.details for e in evs] == [{"writer": winners[i]} for i in range(POP)]
    assert [e.cpu_seconds for e in evs] == [float(winners[i]) for i in range(POP)]
    # attempts: one per claim that found the candidate pending
    claimed = [sum(1 for run in runs.values() for i, _, st in run if i == k and st == "pending")
               for k in range(POP)]
    assert [e.attempts for e in evs] == claimed and all(1 <= a <= WRITERS for a in claimed)
    assert repo.evaluation_counts(job.id, 0) == GenerationCounts(done=POP)


def test_concurrent_claims_are_each_counted(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.5]])
    barrier = threading.Barrier(4)
    seen: list[int] = []

    def run() -> None:
        barrier.wait()
        for _ in range(5):
            seen.append(repo.claim_evaluation(job.id, 0, 0).attempts)

    threads = [threading.Thread(target=run) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert sorted(seen) == list(range(1, 21))  # every claim saw its own increment
    assert get_evaluation(repo, job.id, 0, 0).attempts == 20


def test_release_attempt_gives_back_a_stopped_attempt_only(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.1], [0.2]])
    assert repo.release_attempt(job.id, 0, 0) is False  # nothing counted: stays at 0
    repo.claim_evaluation(job.id, 0, 0)
    repo.claim_evaluation(job.id, 0, 0)
    assert repo.release_attempt(job.id, 0, 0) is True
    assert get_evaluation(repo, job.id, 0, 0).attempts == 1
    repo.claim_evaluation(job.id, 0, 1)
    repo.store_result(job.id, 0, 1, objective=1.0, fell=False, cpu_seconds=0.0)
    assert repo.release_attempt(job.id, 0, 1) is False  # done: its attempt stays counted
    assert get_evaluation(repo, job.id, 0, 1).attempts == 1
    with pytest.raises(NotFound):
        repo.release_attempt(job.id, 0, 9)


def test_the_driver_s_reads_pending_indices_and_rows_without_params(repo: SqlRepository) -> None:
    job = new_job(repo)
    repo.put_pending_evaluations(job.id, 0, [[0.5, 1.5], [2.5, 3.5], [4.5, 5.5]])
    repo.store_result(job.id, 0, 1, objective=2.0, fell=False, cpu_seconds=0.1)
    assert repo.pending_indices(job.id, 0) == [0, 2]
    assert repo.pending_indices(job.id, 1) == []
    full = repo.evaluations(job.id, 0)
    bare = repo.evaluations(job.id, 0, params=False)
    assert [r.params for r in full] == [[0.5, 1.5], [2.5, 3.5], [4.5, 5.5]]
    assert [r.params for r in bare] == [None, None, None]
    # everything else is the same record
    assert [r.__dict__ | {"params": None} for r in full] == [r.__dict__ for r in bare]
    with pytest.raises(NotFound):
        repo.evaluations("no-such-job", 0, params=False)
    assert repo.evaluations(job.id, 7) == []
