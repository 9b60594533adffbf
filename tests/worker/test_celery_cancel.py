"""Cancel on the Celery path with a real `cmrt worker` and Redis: the candidate running when the
job is cancelled is dropped (its worker process killed), the queued ones are never run."""

from __future__ import annotations

import os
import subprocess
import threading
import time
import uuid
from pathlib import Path

import pytest
from proc_helpers import stop_group

from cmrt.settings import Settings
from sim.spec import parse_spec
from store import open_repository
from store.records import CANCELLED, STOPPED
from worker.celery_app import make_celery
from worker.driver import JobDriver
from worker.executors import CeleryExecutor

ROOT = Path(__file__).resolve().parents[2]
REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")


def _spec(name: str) -> dict:
    return {"name": name, "family": "bend",
            "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
            "task": {"type": "pose_change", "target": {"waist": -30}},
            "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0}}


def _job(repo, name):
    spec = parse_spec(_spec(name))
    return repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                           family=spec.family_name, task=spec.task_type,
                           seed=1)


@pytest.mark.redis
def test_cancel_drops_the_running_candidate_and_skips_the_queued(tmp_path):
    import redis

    broker = f"{REDIS}/{9 + uuid.uuid4().int % 6}"
    try:
        redis.Redis.from_url(broker, socket_timeout=2).ping()
    except Exception as err:  # noqa: BLE001
        pytest.skip(f"Redis at {broker} unreachable: {err}")
    db = f"sqlite:///{tmp_path}/c.db"
    settings = Settings(data_dir=tmp_path, database_url=db, broker_url=broker,
                        poll_interval=0.05, dispatch_window=2, queue=f"q{uuid.uuid4().hex[:8]}")
    repo = open_repository(db)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    # every candidate of the job named "stuck" sleeps ten minutes: only a kill ends it
    env.update(CMRT_DATABASE_URL=db, CMRT_BROKER_URL=broker, CMRT_QUEUE=settings.queue,
               CMRT_FAULT_DELAY_ON="stuck:*:*:600")
    log = tmp_path / "worker.log"
    worker = subprocess.Popen([str(ROOT / ".venv/bin/cmrt"), "worker", "--concurrency", "1",
                               "--hostname", f"cancel-{uuid.uuid4().hex[:6]}@%h"],
                              env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT,
                              start_new_session=True)
    app = make_celery(broker, broker, settings)
    ex = CeleryExecutor(settings, app)
    try:
        stuck = _job(repo, "stuck")
        result: dict = {}
        t = threading.Thread(target=lambda: result.setdefault(
            "status", JobDriver(repo, stuck.id, ex, settings).run()))
        t.start()
        t0 = time.monotonic()
        while not any(r.attempts for r in repo.evaluations(stuck.id, 0)):
            assert worker.poll() is None, log.read_text()[-3000:]
            assert time.monotonic() - t0 < 120, "the worker never started a candidate"
            time.sleep(0.05)
        repo.request_cancel(stuck.id)
        t.join(60)
        assert result["status"] == CANCELLED and ex.revoked == 2  # the window's two
        rows = repo.evaluations(stuck.id, 0)
        assert sum(r.attempts for r in rows) == 1  # the queued candidate never started
        # the one running was killed: the single worker process is free for the next job
        nxt = _job(repo, "next")
        assert JobDriver(repo, nxt.id, ex, settings).run() == STOPPED
    finally:
        stop_group(worker)
