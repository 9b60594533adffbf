"""worker.candidates.run_candidates (the body of the Celery task) against the real store, with a
synthetic objective: claim, skip, fail after max_attempts, evaluate, store (first result wins)."""

from __future__ import annotations

import pytest
from local_pool import FactorySpecs
from store_helpers import get_evaluation
from synthetic import Sphere

from optim.outcome import FAILED_OBJECTIVE, EvalOutcome
from store.repository import SqlRepository
from worker.candidates import run_candidates

SPEC = {
    "name": "w_bend", "family": "bend",
    "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.2},
    "task": {"type": "pose_change", "target": {"waist": -30}},
}  # fmt: skip


class Counting:
    """Sphere objective counting its calls (raises for x[0] > 0.9)."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, ...]] = []

    def __call__(self, x) -> EvalOutcome:
        self.calls.append(tuple(x))
        if x[0] > 0.9:
            raise RuntimeError("simulator blew up")
        return Sphere(centre=0.3)(x)


class CountingRepo(SqlRepository):
    """The real repository, counting get_job calls."""

    def __init__(self, engine) -> None:
        super().__init__(engine)
        self.get_job_calls = 0

    def get_job(self, job_id):
        self.get_job_calls += 1
        return super().get_job(job_id)


@pytest.fixture
def setup(repo):
    repo = CountingRepo(repo.engine)
    job = repo.create_job(SPEC, name="w_bend", family="bend", task="pose_change", seed=1)
    repo.set_job_status(job.id, "running")
    objective = Counting()
    cache = FactorySpecs(lambda spec: objective)
    return repo, job.id, objective, cache


def run(repo, job_id, g, i, cache, max_attempts=3):
    """`run_candidates` of one candidate, as the Celery task runs it."""
    return run_candidates(repo, job_id, g, [i], max_attempts=max_attempts, cache=cache,
                          worker_name="w1/42")[0]


def test_candidate_is_evaluated_once_and_its_result_stored(setup) -> None:
    repo, job_id, objective, cache = setup
    repo.put_pending_evaluations(job_id, 0, [[0.5, 0.5], [0.3, 0.3], [0.4, 0.2]])
    out = run(repo, job_id, 0, 0, cache)
    assert out == {"status": "done", "objective": pytest.approx(0.08), "attempts": 1,
                   "changed": True}
    ev = get_evaluation(repo, job_id, 0, 0)
    assert (ev.status, ev.attempts, ev.fell) == ("done", 1, False)
    assert ev.objective == pytest.approx(0.08) and ev.details == {"worker": "w1/42"}
    # a re-delivered message: skipped, nothing counted, the objective not called again
    assert run(repo, job_id, 0, 0, cache) == {"status": "done", "skipped": True}
    assert get_evaluation(repo, job_id, 0, 0).attempts == 1 and len(objective.calls) == 1
    for i in (1, 2):
        assert run(repo, job_id, 0, i, cache)["status"] == "done"
    assert repo.evaluation_counts(job_id, 0).done == 3
    # the spec is read from the store once per process and job, not per candidate
    assert repo.get_job_calls == 1


def test_fall_and_task_verdicts_are_stored_and_read_back_by_the_driver(repo) -> None:
    from worker.driver import _stored_outcome

    job = repo.create_job(SPEC, name="w_bend", family="bend", task="pose_change", seed=1)
    repo.set_job_status(job.id, "running")
    verdict = EvalOutcome(objective=21.5, fell=True, cpu_seconds=0.1, fall_time=1.35,
                          fall_direction="backward", task_success=False)
    cache = FactorySpecs(lambda spec: (lambda x: verdict))
    repo.put_pending_evaluations(job.id, 0, [[0.5, 0.5]])
    assert run(repo, job.id, 0, 0, cache)["status"] == "done"
    row = get_evaluation(repo, job.id, 0, 0)
    assert row.details == {"worker": "w1/42", "fall_time": 1.35, "fall_direction": "backward",
                           "task_success": False}
    assert _stored_outcome(row) == verdict


def test_a_raising_objective_is_stored_as_done_with_the_worst_objective(setup) -> None:
    repo, job_id, _objective, cache = setup
    repo.put_pending_evaluations(job_id, 0, [[0.95, 0.5]])
    assert run(repo, job_id, 0, 0, cache)["status"] == "done"
    ev = get_evaluation(repo, job_id, 0, 0)
    assert ev.status == "done" and ev.objective == FAILED_OBJECTIVE
    assert "simulator blew up" in ev.details["error"]


def test_candidate_of_a_finished_job_is_not_evaluated(setup) -> None:
    repo, job_id, objective, cache = setup
    repo.put_pending_evaluations(job_id, 0, [[0.5, 0.5]])
    repo.set_job_status(job_id, "cancelled")
    assert run(repo, job_id, 0, 0, cache) == {"status": "skipped", "job_status": "cancelled"}
    assert objective.calls == [] and get_evaluation(repo, job_id, 0, 0).status == "pending"


def test_candidate_killing_its_worker_fails_after_max_attempts(setup) -> None:
    repo, job_id, objective, cache = setup
    repo.put_pending_evaluations(job_id, 0, [[0.5, 0.5], [0.6, 0.6]])
    for _ in range(2):  # two starts whose worker process died before storing anything
        repo.claim_evaluation(job_id, 0, 1)
    out = run(repo, job_id, 0, 1, cache, max_attempts=2)
    assert out == {"status": "failed", "attempts": 3}
    ev = get_evaluation(repo, job_id, 0, 1)
    assert ev.status == "failed" and "started 2 times" in ev.error and objective.calls == []
    assert run(repo, job_id, 0, 1, cache, max_attempts=2)["skipped"]
    # its neighbour is evaluated normally
    assert run(repo, job_id, 0, 0, cache, max_attempts=2)["status"] == "done"
    counts = repo.evaluation_counts(job_id, 0)
    assert (counts.done, counts.failed, counts.pending) == (1, 1, 0)


def test_unknown_candidate_is_reported_missing(setup) -> None:
    repo, job_id, objective, cache = setup
    assert run(repo, job_id, 5, 0, cache) == {"status": "missing"}
    assert run(repo, "nope", 0, 0, cache) == {"status": "missing"}
    assert objective.calls == []


def test_store_calls_survive_a_lost_database_connection(repo) -> None:
    """A worker's repository does not ping before each use of a pooled connection: a
    connection the server has dropped fails its next statement, and the call is tried again on a
    new one."""
    from worker.candidates import open_worker_repository

    worker_repo = open_worker_repository(repo.engine.url.render_as_string(hide_password=False))
    engine = worker_repo.engine
    try:
        job = repo.create_job(SPEC, name="w_bend", family="bend", task="pose_change", seed=1)
        repo.set_job_status(job.id, "running")
        repo.put_pending_evaluations(job.id, 0, [[0.5, 0.5], [0.3, 0.3]])
        cache = FactorySpecs(lambda spec: Sphere(centre=0.3))
        assert run(worker_repo, job.id, 0, 0, cache)["status"] == "done"
        if engine.dialect.name == "postgresql":  # drop the pooled connection's session
            from sqlalchemy import text

            with engine.connect() as c:
                pid = c.execute(text("SELECT pg_backend_pid()")).scalar()
            with repo.engine.connect() as c:
                assert c.execute(text("SELECT pg_terminate_backend(:p)"), {"p": pid}).scalar()
        assert run(worker_repo, job.id, 0, 1, cache)["status"] == "done"
        ev = get_evaluation(repo, job.id, 0, 1)
        assert (ev.status, ev.attempts) == ("done", 1)
    finally:
        engine.dispose()


def test_with_reconnect_retries_only_transient_database_errors(monkeypatch) -> None:
    from sqlalchemy.exc import IntegrityError, OperationalError

    from worker import candidates

    monkeypatch.setattr(candidates.time, "sleep", lambda s: None)
    calls = []

    def flaky(x, fail=2, exc=OperationalError):
        calls.append(x)
        if len(calls) <= fail:
            raise exc("SELECT 1", {}, RuntimeError("server closed the connection"))
        return x * 2

    assert candidates.with_reconnect(flaky, 21) == 42 and len(calls) == 3
    calls.clear()
    with pytest.raises(IntegrityError):  # not transient: raised at once
        candidates.with_reconnect(flaky, 1, exc=IntegrityError)
    assert len(calls) == 1
    calls.clear()
    monkeypatch.setattr(candidates, "RECONNECT_SECONDS", 0.0)
    with pytest.raises(OperationalError):  # down for longer than RECONNECT_SECONDS
        candidates.with_reconnect(flaky, 1)
    assert len(calls) == 1
