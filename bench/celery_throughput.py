"""Evaluations per second: Celery workers versus a bare process pool, on the same short clips.

    .venv/bin/python bench/celery_throughput.py [--candidates 32] [--workers 1 2]
        [--clip 0.8 [2.6 ...]] [--repeat 3] [--store N] [--json]

For each worker count N, in the same run and on the same candidates:
  * bare pool: `optim.executors.PoolExecutor(N).map(SimObjective(spec), batch)`;
  * Celery:    `python -m worker --concurrency N` (the compose worker's command) against a
               private redis-server and a fresh PostgreSQL database, driven by the job driver's
               own `CeleryExecutor` (pending evaluations in the store, tasks of up to
               CMRT_TASK_BATCH candidates, results upserted, the driver woken by the workers'
               result notices).
Both sides are warmed up first (processes started, simulators built), then measured `--repeat`
times, alternating, so that both see the same machine load. Prints median evaluations per
second, the ratio Celery / bare pool (target: >= 0.90) and Celery's overhead per candidate in
worker-milliseconds (workers x (1/celery rate - 1/pool rate)), and each side's "busy": the
simulations' own CPU seconds (as each evaluation measured them) over workers x wall seconds,
so that what is lost to the machinery (idle gaps between tasks, CPU taken by the broker, the
database and the Celery parent process) shows apart from slower simulations. It also
accounts, from /proc, the CPU that is not simulation: per candidate, the pool processes' own
CPU besides the simulations (Celery: the store calls and Celery's task wrapper), the Celery
parent process, redis-server, the scratch database's PostgreSQL backends, and this process (the
driver; for the bare pool, the pool's parent). On a machine with as many cores as workers that
CPU is taken from the simulations. The driver
runs with its production settings (CMRT_TASK_BATCH, CMRT_DISPATCH_WINDOW from the environment).
From that account it prints the ratio the CPU alone predicts for an otherwise idle machine with
as many cores as workers, every process CPU-bound and no idle gaps:
(sim + pool overhead) / (sim + Celery overhead), sim being the simulations' own CPU per
candidate. It prints the load average before and after each clip length.
`--store N` also times the worker's store path alone: `worker.candidates.run_candidates` of
one candidate with a
null objective on a worker's repository, N times in this process against the same PostgreSQL
database (median and mean wall ms, mean CPU ms).
No assertions: timings on a shared machine are noisy; run it on an otherwise idle machine for
figures to quote.
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
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

PG_ADMIN = os.environ.get("CMRT_BENCH_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01


def _cpu(pids) -> float:
    """CPU seconds (user + system) used so far by these processes (Linux /proc; 0 elsewhere).
    A process that has exited counts 0."""
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        total += (int(fields[11]) + int(fields[12])) * _TICK_S  # utime, stime
    return total


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


class _CpuAccount:
    """CPU seconds of named groups of processes over one measurement."""

    def __init__(self, groups: dict[str, list[int]]) -> None:
        self.groups = groups
        self.t0 = {k: _cpu(v) for k, v in groups.items()}
        self.p0 = time.process_time()

    def stop(self) -> dict[str, float]:
        out = {k: _cpu(v) - self.t0[k] for k, v in self.groups.items()}
        out["driver"] = time.process_time() - self.p0  # this process: the driver or pool parent
        return out


def _spec(clip: float) -> dict:
    prep = round(clip * 0.4, 3)
    dur = round(clip * 0.4, 3)
    return {
        "name": "bench_bend",
        "family": "bench",
        "clip": {"preparation": prep, "duration": dur, "decay": round(clip - prep - dur, 3)},
        "task": {"type": "pose_change",
                 "target": {"waist": -30, "shoulder_r": 30, "shoulder_l": 30}},
    }


def _batch(spec, n: int, seed: int) -> list[np.ndarray]:
    from optim.spline import flat_params

    rng = np.random.default_rng(seed)
    x0 = flat_params(spec)
    return [np.clip(x0 + 0.1 * rng.standard_normal(len(x0)), 0, 1) for _ in range(n)]


@contextlib.contextmanager
def bare_pool(spec, warm, workers: int):
    """A warmed-up bare pool; yields `measure(batch) -> (eval/s, busy, cpu)`, busy being the
    simulations' own CPU seconds over workers x wall seconds, cpu the CPU seconds of the rest
    (pool processes besides simulating, this process)."""
    from optim.executors import PoolExecutor
    from optim.objective import SimObjective

    fn = SimObjective(spec)
    with PoolExecutor(workers) as pool:
        pool.map(fn, warm)

        def measure(batch) -> tuple[float, float, dict[str, float]]:
            procs = pool.pids()
            acct = _CpuAccount({"children": procs})
            t0 = time.perf_counter()
            outs = pool.map(fn, batch)
            dt = time.perf_counter() - t0
            cpu = acct.stop()
            assert all(o.error is None for o in outs)
            sim = sum(o.cpu_seconds for o in outs)
            cpu["children"] -= sim  # what the pool processes spent besides simulating
            cpu["wall"] = dt
            cpu["sim"] = sim
            return len(batch) / dt, sim / (workers * dt), cpu

        yield measure


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


@contextlib.contextmanager
def celery(spec, warm, workers: int, scratch: _Scratch):
    """A warmed-up Celery worker (the compose command) and the driver's executor; yields
    `measure(batch) -> (eval/s, repeated attempts, busy, cpu)`, one new generation per call;
    cpu: CPU seconds of the worker's pool processes besides simulating, of its parent, of Redis,
    of the scratch database's PostgreSQL backends and of this process (the driver)."""
    import sqlalchemy as sa

    from cmrt.settings import Settings
    from store import open_repository
    from worker import faults
    from worker.celery_app import make_celery
    from worker.executors import CeleryExecutor

    env = dict(os.environ, CMRT_DATABASE_URL=scratch.db_url, CMRT_BROKER_URL=scratch.broker,
               PYTHONUNBUFFERED="1")
    for k in faults.ENV_VARS:
        env.pop(k, None)
    repo = open_repository(scratch.db_url)
    settings = Settings(database_url=scratch.db_url, broker_url=scratch.broker)
    cfg = settings
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
                              task=s.task_type, seed=0)

        def check() -> None:
            if proc.poll() is not None:
                raise RuntimeError(f"worker exited: see {log.name}")

        repo.put_pending_evaluations(job.id, 0, [list(map(float, x)) for x in warm])
        ex.evaluate(repo, job.id, 0, len(warm), check)
        generation = 0

        def backends() -> list[int]:
            with repo.engine.connect() as c:
                return [int(r[0]) for r in c.execute(sa.text(
                    "SELECT pid FROM pg_stat_activity WHERE datname = current_database()"))]

        def measure(batch) -> tuple[float, int, float, dict[str, float]]:
            nonlocal generation
            generation += 1
            repo.put_pending_evaluations(job.id, generation, [list(map(float, x)) for x in batch])
            acct = _CpuAccount({"children": _children(proc.pid), "parent": [proc.pid],
                                "redis": [scratch.redis.pid], "postgres": backends()})
            t0 = time.perf_counter()
            rows = ex.evaluate(repo, job.id, generation, len(batch), check)
            dt = time.perf_counter() - t0
            cpu = acct.stop()
            assert all(r.status == "done" for r in rows)
            sim = sum(r.cpu_seconds or 0.0 for r in rows)
            cpu["children"] -= sim
            cpu["wall"] = dt
            cpu["sim"] = sim
            busy = sim / (workers * dt)
            return len(batch) / dt, sum(r.attempts - 1 for r in rows), busy, cpu

        yield measure
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        repo.engine.dispose()


def store_path(spec, n: int, scratch: _Scratch) -> dict:
    """Median and mean ms of `run_candidates` of one candidate with a null objective (claim,
    result; no Celery)."""
    from worker.candidates import JobSpecs, open_worker_repository, run_candidates

    repo = open_worker_repository(scratch.db_url)  # as in a Celery worker process
    try:
        job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                              family=spec.family_name, task=spec.task_type, seed=0)
        repo.set_job_status(job.id, "running")
        class Null(JobSpecs):  # every job's objective is 1.0 at once
            def get(self, repo, job_id):
                return super().get(repo, job_id)[0], lambda _x: 1.0

        cache = Null()
        pop, times, cpu = 16, [], 0.0
        for g in range(100, 100 + (n + pop - 1) // pop + 1):
            repo.put_pending_evaluations(job.id, g, [[0.5] * spec.cmrt_dimension] * pop)
            for i in range(pop):
                t0, c0 = time.perf_counter(), time.process_time()
                out = run_candidates(repo, job.id, g, [i], max_attempts=3, cache=cache,
                                     worker_name="bench")[0]
                if g > 100:  # the first generation warms up (connection, statements)
                    times.append(time.perf_counter() - t0)
                    cpu += time.process_time() - c0
                assert out["status"] == "done", out
        return {"store_ms_median": 1e3 * statistics.median(times),
                "store_ms_mean": 1e3 * statistics.mean(times),
                "store_cpu_ms_mean": 1e3 * cpu / len(times), "store_n": len(times)}
    finally:
        repo.engine.dispose()


def _add(total: dict[str, float], part: dict[str, float]) -> None:
    for k, v in part.items():
        total[k] = total.get(k, 0.0) + v


def _per_candidate(total: dict[str, float], candidates: int) -> dict[str, float]:
    """ms per candidate from seconds summed over measurements of `candidates` in all."""
    return {k: 1e3 * v / candidates for k, v in total.items()}


def _overhead(parts: dict[str, float]) -> float:
    """Not-simulation CPU ms per candidate: every account but the wall time and the simulation."""
    return sum(v for k, v in parts.items() if k not in ("wall", "sim"))


def measure_clip(args: argparse.Namespace, clip: float, scratch: _Scratch) -> list[dict]:
    """Every worker count's alternating measurements of one clip length."""
    from sim.spec import parse_spec

    spec = parse_spec(_spec(clip))
    batch = _batch(spec, args.candidates, 1)
    rows = []
    for n in args.workers:
        warm = _batch(spec, 2 * n, 100 + n)
        pool_rates, cel_rates, repeated, pool_busy, cel_busy = [], [], 0, [], []
        pool_cpu: dict[str, float] = {}
        cel_cpu: dict[str, float] = {}
        load0 = os.getloadavg()[0]
        with bare_pool(spec, warm, n) as pool, celery(spec, warm, n, scratch) as cel:
            for _ in range(args.repeat):  # alternate, so both see the same machine load
                rate, busy, cpu = pool(batch)
                pool_rates.append(rate)
                pool_busy.append(busy)
                _add(pool_cpu, cpu)
                rate, rep, busy, cpu = cel(batch)
                cel_rates.append(rate)
                cel_busy.append(busy)
                _add(cel_cpu, cpu)
                repeated += rep
        ratios = [c / p for c, p in zip(cel_rates, pool_rates, strict=True)]
        measured = len(batch) * args.repeat
        pool_rate = statistics.median(pool_rates)
        cel_rate = statistics.median(cel_rates)
        pool_ms = _per_candidate(pool_cpu, measured)
        cel_ms = _per_candidate(cel_cpu, measured)
        sim_ms = 0.5 * (pool_ms["sim"] + cel_ms["sim"])
        rows.append({"clip": clip, "workers": n, "pool_eval_per_s": pool_rate,
                     "celery_eval_per_s": cel_rate, "ratio": statistics.median(ratios),
                     "ratios": ratios,
                     "overhead_ms": 1e3 * n * (1 / cel_rate - 1 / pool_rate),
                     "repeated": repeated,
                     "pool_busy": statistics.median(pool_busy),
                     "celery_busy": statistics.median(cel_busy),
                     "pool_cpu_ms_per_candidate": pool_ms,
                     "celery_cpu_ms_per_candidate": cel_ms,
                     "pool_overhead_ms": _overhead(pool_ms),
                     "celery_overhead_ms": _overhead(cel_ms),
                     "predicted_idle_ratio": (sim_ms + _overhead(pool_ms))
                     / (sim_ms + _overhead(cel_ms)),
                     "load": [load0, os.getloadavg()[0]]})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--candidates", type=int, default=32)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--clip", type=float, nargs="+", default=[0.8],
                   help="clip lengths in seconds (each measured in turn)")
    p.add_argument("--repeat", type=int, default=3,
                   help="measurements per side, alternating pool and Celery (medians shown)")
    p.add_argument("--store", type=int, default=0, metavar="N",
                   help="also time run_candidates (one candidate) with a null objective N times")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    from cmrt.settings import get_settings
    from sim.spec import parse_spec

    scratch = _Scratch()
    rows = []
    try:
        for clip in args.clip:
            rows += measure_clip(args, clip, scratch)
        store = (store_path(parse_spec(_spec(args.clip[0])), args.store, scratch)
                 if args.store > 0 else None)
    finally:
        scratch.close()
    cfg = get_settings()
    if args.json:
        print(json.dumps({"rows": rows, "store": store, "task_batch": cfg.task_batch,
                          "dispatch_window": cfg.dispatch_window}, indent=1))
        return 0
    print(f"{args.candidates} candidates per measurement, median of {args.repeat} alternating "
          f"measurements per side; CMRT_TASK_BATCH {cfg.task_batch}, CMRT_DISPATCH_WINDOW "
          f"{cfg.dispatch_window}")
    print(f"{'clip s':>6} {'workers':>7} {'pool eval/s':>12} {'celery eval/s':>14} {'ratio':>6} "
          f"{'busy pool':>9} {'busy celery':>11} {'CPU model':>9} {'load':>9}")
    for r in rows:
        print(f"{r['clip']:>6g} {r['workers']:>7} {r['pool_eval_per_s']:>12.2f} "
              f"{r['celery_eval_per_s']:>14.2f} {r['ratio']:>6.1%} {r['pool_busy']:>9.1%} "
              f"{r['celery_busy']:>11.1%} {r['predicted_idle_ratio']:>9.1%} "
              f"{r['load'][0]:>4.1f}-{r['load'][1]:<4.1f}"
              + (f"   ratios {' '.join(f'{x:.0%}' for x in r['ratios'])}" if args.repeat > 1
                 else ""))
    print("CPU ms per candidate (all measurements): the simulation ('sim'), the rest by process "
          "('wall' is wall ms per candidate); 'CPU model': (sim + pool rest) / (sim + Celery "
          "rest), the ratio on an idle machine with a core per worker")
    for r in rows:
        for side in ("pool", "celery"):
            parts = r[f"{side}_cpu_ms_per_candidate"]
            print(f"  {r['clip']:g} s, {r['workers']} worker(s), {side:>6}: rest "
                  f"{r[f'{side}_overhead_ms']:.2f} = " + ", ".join(
                      f"{k} {v:.2f}" for k, v in parts.items() if k not in ("wall", "sim"))
                  + f"; sim {parts['sim']:.1f}, wall {parts['wall']:.1f}")
    if store:
        print(f"store path (run_candidates, null objective, PostgreSQL): median "
              f"{store['store_ms_median']:.2f} ms, mean {store['store_ms_mean']:.2f} ms, "
              f"CPU {store['store_cpu_ms_mean']:.2f} ms over {store['store_n']} candidates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
