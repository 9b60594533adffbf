"""A robust job (`optimize.robust`) on a real `cmrt worker` (2 processes) and Redis: every
variant of every candidate is its own evaluation the workers share, the job gives the command
line's result by repr, records each variant's outcome, and its library entry answers a query
inside its range (`source: robust`, verified at the query's value)."""

from __future__ import annotations

import os
import subprocess
import uuid
from pathlib import Path

import pytest
from proc_helpers import stop_group

from application import answers
from cmrt.settings import Settings
from optim.clips import run_clip
from optim.executors import SerialExecutor
from optim.run import optimize
from sim.spec import parse_canonical
from store import open_repository
from store.records import STOPPED
from worker.celery_app import make_celery
from worker.driver import JobDriver
from worker.executors import CeleryExecutor

pytestmark = pytest.mark.redis

ROOT = Path(__file__).resolve().parents[2]
REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")
SPEC = {"name": "robust_bend", "family": "robust_bend",
        "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0,
                     "robust": {"vary": {"clip.duration": [0.15, 0.25]}, "samples": 3}}}


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
    tmp = tmp_path_factory.mktemp("robust")
    broker = _broker()
    db = f"sqlite:///{tmp}/r.db"
    settings = Settings(data_dir=tmp, database_url=db, broker_url=broker, workers=2,
                        dispatch_window=4, task_batch=2, queue=f"q{uuid.uuid4().hex[:8]}")
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=db, CMRT_BROKER_URL=broker, CMRT_QUEUE=settings.queue)
    worker = subprocess.Popen([str(ROOT / ".venv/bin/cmrt"), "worker", "--concurrency", "2",
                               "--hostname", f"robust-{uuid.uuid4().hex[:6]}@%h"],
                              env=env, stdout=(tmp / "worker.log").open("wb"),
                              stderr=subprocess.STDOUT, start_new_session=True)
    try:
        yield settings, open_repository(db)
    finally:
        stop_group(worker)


def test_a_robust_job_spreads_its_variants_and_equals_the_command_line(celery_worker):
    settings, repo = celery_worker
    canonical = parse_canonical(SPEC)
    job = repo.create_job(canonical.document, name="robust_bend", family="robust_bend",
                          task="pose_change", seed=1)
    ex = CeleryExecutor(settings, make_celery(settings.broker_url, settings.broker_url,
                                              settings))
    assert JobDriver(repo, job.id, ex, settings).run() == STOPPED
    # 2 generations of 4 candidates x 3 variants, and the final 2 x 3: one evaluation each
    rows = {g: repo.evaluations(job.id, g) for g in (0, 1, -1)}
    assert [len(rows[g]) for g in (0, 1, -1)] == [12, 12, 6] and ex.sent == 30
    # each stored evaluation is a candidate's params and its variant's index
    assert [r.params[-1] for r in rows[0]] == [0.0, 1.0, 2.0] * 4
    assert rows[0][0].params[:-1] == rows[0][2].params[:-1]
    cli = optimize(canonical, SerialExecutor(), seed=1).to_dict()
    got = repo.job_result(job.id)
    for key in ("objective", "params", "baseline_objective", "history", "robust"):
        assert repr(got[key]) == repr(cli[key]), key
    assert [v["values"]["clip.duration"] for v in got["robust"]["variants"]] == \
        [0.15, 0.2, 0.25]

    # the library keeps it with its range and answers inside it
    cover = answers.robust_cover(repo, "robust_bend", "duration", 0.17)
    assert cover is not None and cover[1] == {"path": "clip.duration", "range": [0.15, 0.25],
                                              "samples": 3, "aggregate": "mean"}
    assert answers.robust_cover(repo, "robust_bend", "duration", 0.3) is None
    plain = answers.serve(repo, answers.LibraryQuery("robust_bend", {"duration": 0.17}))
    assert plain.source == "robust" and plain.robust["id"] == cover[0].id
    assert plain.members == [cover[0].id]
    assert "was optimised for duration from 0.15 to 0.25 (3 variants" in plain.message
    a = answers.serve(repo, answers.LibraryQuery("robust_bend", {"duration": 0.17}),
                      lambda doc, params: run_clip(doc, params, False, False))
    assert a.verified and a.tried[0]["source"] == "robust"
    assert a.tried[0]["outcome"]["status"] == "done"
    # simulated at the query's value: the clip of duration 0.17, not the CMRT's own 0.2
    at = parse_canonical({**SPEC, "clip": {**SPEC["clip"], "duration": 0.17},
                          "optimize": {k: v for k, v in SPEC["optimize"].items()
                                       if k != "robust"}})
    assert a.tried[0]["outcome"]["spec_hash"] == at.hash
