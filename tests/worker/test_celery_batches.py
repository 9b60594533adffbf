"""Batched evaluation tasks and result notices with a real `cmrt worker` (2 processes) and Redis:
a job driven through Celery gives the same generations, bit for bit, as the same job on the
local pool; a worker process killed in the middle of a batch loses only the candidate it was
running (the re-delivered task skips the ones already stored); the notices reach the driver; a
message of the retired single-candidate task is refused with its reason logged."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
import uuid
from pathlib import Path

import pytest
from local_pool import local_executor
from proc_helpers import stop_group

from cmrt.settings import Settings
from optim.executors import SerialExecutor
from sim.spec import parse_spec
from store import open_repository
from store.records import DONE, STOPPED
from worker.celery_app import make_celery
from worker.driver import JobDriver
from worker.executors import CeleryExecutor
from worker.notify import NoticeWaiter, Notifier, notice_key

pytestmark = pytest.mark.redis

ROOT = Path(__file__).resolve().parents[2]
REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")
#: Candidate 1 of generation 0 of the job named "held" sleeps this long before it runs, s: the
#: time the kill test has to strike while the batch [0, 1] is half done.
HOLD_S = 2.0


def _spec(name: str) -> dict:
    return {"name": name, "family": "bend",
            "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
            "task": {"type": "pose_change", "target": {"waist": -30}},
            "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}}


def _job(repo, name: str, seed: int = 1):
    spec = parse_spec(_spec(name))
    return repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                           family=spec.family_name, task=spec.task_type, seed=seed)


def _broker() -> str:
    import redis

    broker = f"{REDIS}/{9 + uuid.uuid4().int % 6}"
    try:
        redis.Redis.from_url(broker, socket_timeout=2).ping()
    except Exception as err:  # noqa: BLE001
        pytest.skip(f"Redis at {broker} unreachable: {err}")
    return broker


@pytest.fixture(scope="module")
def celery_worker(tmp_path_factory):
    """A real `cmrt worker --concurrency 2` on a private queue, its settings and repository."""
    tmp = tmp_path_factory.mktemp("batches")
    broker = _broker()
    db = f"sqlite:///{tmp}/b.db"
    settings = Settings(data_dir=tmp, database_url=db, broker_url=broker, workers=2,
                        dispatch_window=4, task_batch=2, queue=f"q{uuid.uuid4().hex[:8]}")
    repo = open_repository(db)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=db, CMRT_BROKER_URL=broker, CMRT_QUEUE=settings.queue,
               CMRT_FAULT_DELAY_ON=f"held:0:1:{HOLD_S:g}")
    log = tmp / "worker.log"
    worker = subprocess.Popen([str(ROOT / ".venv/bin/cmrt"), "worker", "--concurrency", "2",
                               "--hostname", f"batch-{uuid.uuid4().hex[:6]}@%h"],
                              env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT,
                              start_new_session=True)
    try:
        yield settings, repo, worker, log
    finally:
        stop_group(worker)


def _executor(settings) -> CeleryExecutor:
    return CeleryExecutor(settings, make_celery(settings.broker_url, settings.broker_url,
                                                settings))


def test_batched_celery_job_matches_the_local_pool_bit_for_bit(celery_worker):
    settings, repo, _worker, _log = celery_worker
    ex = _executor(settings)
    job = _job(repo, "same")
    assert JobDriver(repo, job.id, ex, settings).run() == STOPPED
    # 2 generations of 4 in tasks of 2 (then 1 + 1 at each generation's end), the final pair
    # as 1 + 1: fewer tasks than candidates, every candidate evaluated once
    assert ex.sent == 10 and ex.tasks < ex.sent and ex.resent == 0
    assert ex._waiter.available  # the driver waited on notices, not on polls
    rows = [r for g in (0, 1, -1) for r in repo.evaluations(job.id, g)]
    assert len(rows) == 10 and all((r.status, r.attempts) == (DONE, 1) for r in rows)

    ref = _job(repo, "same")
    local = local_executor(settings, SerialExecutor())  # the real objective
    assert JobDriver(repo, ref.id, local, settings).run() == STOPPED
    a, b = repo.get_job(job.id), repo.get_job(ref.id)
    assert [g.best for g in repo.generations(job.id)] == \
        [g.best for g in repo.generations(ref.id)]
    assert a.best_objective == b.best_objective and a.best_params == b.best_params
    assert repo.job_cmrt(job.id).params == repo.job_cmrt(ref.id).params


def test_the_worker_reports_its_numeric_fingerprint_and_its_evaluations_carry_it(
        celery_worker):
    import redis

    from sim.fingerprint import numeric_fingerprint
    from worker.fingerprints import KEY_PREFIX, TTL_SECONDS, live_fingerprints

    settings, repo, worker, log = celery_worker
    job = _job(repo, "printed")
    assert JobDriver(repo, job.id, _executor(settings), settings).run() == STOPPED
    mine = numeric_fingerprint().digest  # this process: another BLAS kernel, the same bits
    assert repo.evaluation_fingerprints(job.id) == [mine]
    assert f"numeric fingerprint {mine}" in log.read_text()
    client = redis.Redis.from_url(settings.broker_url)
    host = repo.evaluations(job.id, 0)[0].details["worker"].rsplit("/", 1)[0]
    assert live_fingerprints(client)[host] == mine
    assert 0 < client.ttl(KEY_PREFIX + host) <= TTL_SECONDS  # a dead worker's entry expires
    app = make_celery(settings.broker_url, settings.broker_url, settings)
    stats = app.control.inspect(destination=[host], timeout=5.0).stats()
    assert stats[host]["cmrt_fingerprint"]["fingerprint"] == mine
    reply = app.control.inspect(destination=[host], timeout=5.0)._request("fingerprint")
    assert reply[host]["fingerprint"] == mine and reply[host]["versions"]["numba"]
    assert worker.poll() is None


def test_worker_killed_mid_batch_loses_only_its_running_candidate(celery_worker):
    settings, repo, worker, log = celery_worker
    ex = _executor(settings)
    job = _job(repo, "held")
    result: dict = {}
    t = threading.Thread(target=lambda: result.setdefault(
        "status", JobDriver(repo, job.id, ex, settings).run()))
    t.start()
    try:
        t0 = time.monotonic()
        while True:  # batch [0, 1]: candidate 0 stored, candidate 1 held by the delay hook
            rows = repo.evaluations(job.id, 0)
            if len(rows) == 4 and rows[0].status == DONE and rows[1].attempts == 1:
                break
            assert worker.poll() is None, log.read_text()[-3000:]
            assert time.monotonic() - t0 < 60, [(r.status, r.attempts) for r in rows]
            time.sleep(0.02)
        pid = int(rows[0].details["worker"].rsplit("/", 1)[1])  # it runs the whole batch
        os.kill(pid, signal.SIGKILL)
    finally:
        t.join(120)
    assert result.get("status") == STOPPED, log.read_text()[-3000:]
    rows = repo.evaluations(job.id, 0)
    assert [r.status for r in rows] == [DONE] * 4
    # the re-delivered batch skipped candidate 0 and ran candidate 1 again; nothing else
    assert [r.attempts for r in rows] == [1, 2, 1, 1]
    assert worker.poll() is None  # the worker replaced its pool process


def test_notices_reach_the_waiter_and_a_dead_redis_falls_back_to_polling():
    broker = _broker()
    job = f"job-{uuid.uuid4().hex[:8]}"
    waiter, notifier = NoticeWaiter(broker), Notifier(broker)
    try:
        assert waiter.wait(job, 0.05) == []  # nothing yet: a timeout
        assert notifier.notify(job, 3, 1) and notifier.notify(job, 3, 0)
        t0 = time.monotonic()
        assert waiter.wait(job, 5.0) == [(3, 1), (3, 0)]
        assert time.monotonic() - t0 < 1.0  # no waiting once a notice is there
        # a notice arriving while the driver waits wakes it
        threading.Timer(0.2, notifier.notify, (job, 4, 2)).start()
        assert waiter.wait(job, 5.0) == [(4, 2)]
    finally:
        waiter.discard(job)
    import redis

    assert redis.Redis.from_url(broker).exists(notice_key(job)) == 0
    dead = "redis://127.0.0.1:1/0"  # nothing listens there
    assert Notifier(dead).notify(job, 0, 0) is False
    assert NoticeWaiter(dead).wait(job, 0.05) is None
    assert NoticeWaiter("memory://").wait(job, 0.05) is None  # not Redis: no notices
