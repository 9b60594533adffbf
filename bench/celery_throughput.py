"""Evaluations per second: Celery workers versus a bare process pool, on the same short clips.

    .venv/bin/python bench/celery_throughput.py [--candidates 32] [--workers 1 2] [--clip 0.8]

For each worker count N, in the same run and on the same candidates:
  * bare pool: `optim.executors.PoolExecutor(N).map(SimObjective(spec), batch)`;
  * Celery:    `python -m worker --concurrency N` (the compose worker's command) against a
               private redis-server and a fresh PostgreSQL database, driven by the job driver's
               own `CeleryExecutor` (pending evaluations in the store, one task per candidate,
               results upserted, completion by polling the store's counts).
Both sides are warmed up first (processes started, simulators built). Prints evaluations per
second and the ratio Celery / bare pool (target: >= 0.90). No assertions: timings on a shared
machine are noisy; run it on an otherwise idle machine for figures to quote.
Needs redis-server on PATH and PostgreSQL (CMRT_BENCH_PG, default
postgresql+psycopg://postgres@127.0.0.1:5432/test, as admin URL to create a scratch database).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_ADMIN = os.environ.get("CMRT_BENCH_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spec(clip: float) -> dict:
    prep = round(clip * 0.4, 3)
    dur = round(clip * 0.4, 3)
    return {
        "name": "bench_bend",
        "family": "bench",
        "task": "pose_change",
        "clip": {"preparation": prep, "duration": dur, "decay": round(clip - prep - dur, 3)},
        "pose_change": {"target": {"waist": -30, "shoulder_r": 30, "shoulder_l": 30}},
    }


def _batch(spec, n: int, seed: int) -> list[np.ndarray]:
    from optim.spline import flat_params

    rng = np.random.default_rng(seed)
    x0 = flat_params(spec)
    return [np.clip(x0 + 0.1 * rng.standard_normal(len(x0)), 0, 1) for _ in range(n)]


def bare_pool(spec, batch, warm, workers: int) -> float:
    from optim.executors import PoolExecutor
    from optim.objective import SimObjective

    fn = SimObjective(spec)
    with PoolExecutor(workers) as pool:
        pool.map(fn, warm)
        t0 = time.perf_counter()
        outs = pool.map(fn, batch)
        dt = time.perf_counter() - t0
    assert all(o.error is None for o in outs)
    return len(batch) / dt


class _Scratch:
    """A private redis-server and a scratch PostgreSQL database."""

    def __init__(self) -> None:
        import sqlalchemy as sa

        self.dir = Path(tempfile.mkdtemp(prefix="cmrt-bench-"))
        self.redis_port = _port()
        self.redis = subprocess.Popen(
            ["redis-server", "--port", str(self.redis_port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(self.dir)],
            stdout=subprocess.DEVNULL, start_new_session=True)
        self.db = f"cmrt_bench_{uuid.uuid4().hex[:8]}"
        admin = sa.create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'CREATE DATABASE "{self.db}"'))
        admin.dispose()
        self.db_url = PG_ADMIN.rsplit("/", 1)[0] + "/" + self.db
        self.broker = f"redis://127.0.0.1:{self.redis_port}/0"
        time.sleep(0.5)

    def close(self) -> None:
        import sqlalchemy as sa

        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.redis.pid, signal.SIGKILL)
        admin = sa.create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'DROP DATABASE IF EXISTS "{self.db}" WITH (FORCE)'))
        admin.dispose()
        if not os.environ.get("CMRT_BENCH_KEEP"):
            shutil.rmtree(self.dir, ignore_errors=True)


def celery(spec, batch, warm, workers: int, scratch: _Scratch) -> tuple[float, dict]:
    from cmrt.settings import Settings
    from store import open_repository
    from worker.celery_app import make_celery
    from worker.config import WorkerConfig
    from worker.executors import CeleryExecutor

    env = dict(os.environ, CMRT_DATABASE_URL=scratch.db_url, CMRT_BROKER_URL=scratch.broker,
               PYTHONUNBUFFERED="1")
    env.pop("CMRT_FAULT_CRASH_ON", None)
    repo = open_repository(scratch.db_url)
    settings = Settings(database_url=scratch.db_url, broker_url=scratch.broker)
    cfg = WorkerConfig(settings, poll_interval=0.05)
    app = make_celery(scratch.broker, scratch.broker, cfg)
    ex = CeleryExecutor(cfg, app)
    log = open(scratch.dir / f"worker{workers}.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "worker", "--concurrency", str(workers),
                             "--loglevel", os.environ.get("CMRT_BENCH_LOGLEVEL", "WARNING"),
                             "--hostname", f"bench{workers}@%h"],
                            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        s = spec
        job = repo.create_job(s.model_dump(mode="json"), name=s.name, family=s.family_name,
                              task=s.task, seed=0)
        ev = threading.Event()

        def check() -> None:
            if proc.poll() is not None:
                raise RuntimeError(f"worker exited: see {log.name}")
            if ev.is_set():
                raise RuntimeError("interrupted")

        repo.put_pending_evaluations(job.id, 0, [list(map(float, x)) for x in warm])
        ex.evaluate(repo, job.id, job.spec, 0, len(warm), check)
        repo.put_pending_evaluations(job.id, 1, [list(map(float, x)) for x in batch])
        t0 = time.perf_counter()
        rows = ex.evaluate(repo, job.id, job.spec, 1, len(batch), check)
        dt = time.perf_counter() - t0
        assert all(r.status == "done" for r in rows)
        return len(batch) / dt, {"repeated": sum(r.attempts - 1 for r in rows)}
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        repo.engine.dispose()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--candidates", type=int, default=32)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--clip", type=float, default=0.8, help="clip length in seconds")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    from sim.spec import parse_spec

    spec = parse_spec(_spec(args.clip))
    batch = _batch(spec, args.candidates, 1)
    scratch = _Scratch()
    rows = []
    try:
        for n in args.workers:
            warm = _batch(spec, 2 * n, 100 + n)
            pool_rate = bare_pool(spec, batch, warm, n)
            cel_rate, extra = celery(spec, batch, warm, n, scratch)
            rows.append({"workers": n, "pool_eval_per_s": pool_rate,
                         "celery_eval_per_s": cel_rate, "ratio": cel_rate / pool_rate, **extra})
    finally:
        scratch.close()
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"clip {args.clip:g} s, {args.candidates} candidates per measurement")
    print(f"{'workers':>7} {'pool eval/s':>12} {'celery eval/s':>14} {'ratio':>6}")
    for r in rows:
        print(f"{r['workers']:>7} {r['pool_eval_per_s']:>12.2f} {r['celery_eval_per_s']:>14.2f} "
              f"{r['ratio']:>6.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
