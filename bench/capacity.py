"""Capacity of one service, by simulation: how many candidates per second one driver, one Redis
and one PostgreSQL sustain when many Celery worker processes evaluate, each evaluation costing
a fixed wall time and no CPU, so that this machine's cores stand in for hundreds of workers.

    .venv/bin/python bench/capacity.py [--workers 8 32 128 256] [--eval 1.0 0.1]
        [--per-instance 32] [--popsize 16] [--jobs-per-worker 0.1] [--seconds 20] [--json]
        [--driver-from CHECKOUT ...] [--repeat N]

For each worker count W and evaluation time S, on a fresh database and broker:
  * a private PostgreSQL cluster (`initdb` as the `postgres` user, `max_connections` above the
    worker processes: every worker process holds one connection) and a private redis-server;
  * the real driver, `cmrt driver` (job drivers, scanner, `CeleryExecutor` with the production
    settings; CMRT_DISPATCH_WINDOW set to the popsize, so a job can have its whole generation
    out, as docs/service.md asks of a window "about twice the worker processes" per job);
  * W worker processes: ceil(W / --per-instance) instances of the product's worker command
    (`cmrt worker`, prefork, `--concurrency` up to --per-instance: one instance stands for one
    host), whose objective is `SleepingObjective(S)` (below), set through the product's
    job cache (`worker.tasks._cache`, a `worker.candidates.JobSpecs` whose objective sleeps) before
    Celery forks: the worker runs every store call, notice
    and Celery step of a real evaluation, only the simulation is a sleep;
  * J = max(4, ceil(--jobs-per-worker x W)) jobs... at least enough candidates in flight to
    keep W workers busy (J x popsize >= 1.25 W), created queued in the store (the driver's
    scanner takes them, as it takes a job the API created), spec `bench_capacity` with
    `min_evaluations = max_evaluations` (no stopping rule fires while measured).
After every job has finished a few generations, `--seconds` of wall time are measured:
candidates stored per second (the store's count of done evaluations, before and after), each
job's share (min / max of the jobs' rates, and Jain's fairness index: 1 = equal shares), the
workers' busy fraction (candidates/s x S / W) and the CPU seconds per candidate of the driver,
redis-server, the PostgreSQL cluster and the workers (parents and pool processes), from /proc;
each process's CPU is the limit of its own rate (one Python process uses at most one core:
1000 / its ms per candidate). Memory: the workers' proportional set size (PSS) per process.
`--driver-from A B` runs the driver's code from other checkouts of the project (each on
PYTHONPATH, the workers' code from this one), each point measured with A, then B, `--repeat`
times: a before/after of a driver change in one run, under the same load.
Needs redis-server and PostgreSQL's server binaries (initdb, pg_ctl), and root (to run them as
`postgres`). No assertions: figures go to docs/service.md ("Scaling out") with the load.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.celery_throughput import _cpu  # the same CPU account
from optim.outcome import EvalOutcome

ROOT = Path(__file__).resolve().parents[1]
#: PostgreSQL connections kept free beside the workers' (driver, scanner, this script).
PG_SPARE_CONNECTIONS = 50


def _port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _children(pid: int) -> list[int]:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _pss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _spec(popsize: int, evaluations: int) -> dict[str, Any]:
    return {
        "name": "bench_capacity", "family": "bench",
        "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30, "shoulder_r": 30,
                                                     "shoulder_l": 30}},
        "optimize": {"popsize": popsize, "min_evaluations": evaluations,
                     "max_evaluations": evaluations},
    }


class PrivatePostgres:
    """A throw-away PostgreSQL cluster run as the `postgres` user, `max_connections` given."""

    def __init__(self, max_connections: int) -> None:
        bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
        if not bins:
            raise SystemExit("capacity: PostgreSQL's initdb not found (/usr/lib/postgresql)")
        self.bin = Path(bins[-1]).parent
        self.dir = Path(tempfile.mkdtemp(prefix="cmrt-capacity-pg-"))
        shutil.chown(self.dir, "postgres", "postgres")
        self.port = _port()
        self._as_pg([str(self.bin / "initdb"), "-D", str(self.dir / "data"), "-A", "trust",
                     "-U", "postgres", "--no-sync"])
        self._as_pg([str(self.bin / "pg_ctl"), "-D", str(self.dir / "data"), "-l",
                     str(self.dir / "log"), "-w", "-o",
                     f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 "
                     f"-c max_connections={max_connections} -c shared_buffers=128MB", "start"])
        self.pid = int((self.dir / "data" / "postmaster.pid").read_text().split()[0])

    def _as_pg(self, cmd: list[str]) -> None:
        subprocess.run(["runuser", "-u", "postgres", "--", *cmd], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def url(self, db: str) -> str:
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/{db}"

    def create(self, db: str) -> str:
        import sqlalchemy as sa

        admin = sa.create_engine(self.url("postgres"), isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)'))
            c.execute(sa.text(f'CREATE DATABASE "{db}"'))
        admin.dispose()
        return self.url(db)

    def pids(self) -> list[int]:
        return [self.pid, *_children(self.pid)]

    def close(self) -> None:
        with contextlib.suppress(subprocess.CalledProcessError):
            self._as_pg([str(self.bin / "pg_ctl"), "-D", str(self.dir / "data"), "-m",
                         "immediate", "stop"])
        shutil.rmtree(self.dir, ignore_errors=True)


class Redis:
    def __init__(self) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="cmrt-capacity-redis-"))
        self.port = _port()
        self.proc = subprocess.Popen(
            ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(self.dir), "--maxclients", "10000"],
            stdout=subprocess.DEVNULL, start_new_session=True)
        self.url = f"redis://127.0.0.1:{self.port}/0"
        time.sleep(0.3)

    def close(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        shutil.rmtree(self.dir, ignore_errors=True)


def _stop(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _done_by_job(repo: Any) -> dict[str, int]:
    import sqlalchemy as sa

    with repo.engine.connect() as c:
        rows = c.execute(sa.text(
            "SELECT job_id, count(*) FROM evaluations WHERE status = 'done' AND generation >= 0 "
            "GROUP BY job_id")).all()
    return {j: int(n) for j, n in rows}


def measure(workers: int, sleep: float, args: argparse.Namespace, pg: PrivatePostgres,
            log_dir: Path, driver_root: Path = ROOT) -> dict[str, Any]:
    """One point of the curve (see the module docstring), the driver's code from the checkout
    `driver_root` (the workers' from this one)."""
    from sim.spec import parse_spec
    from store import open_repository

    tag = f"w{workers}_s{sleep:g}_{driver_root.name}_{int(time.time())}".replace(".", "p")
    redis = Redis()
    url = pg.create(f"cap_{tag}")
    repo = open_repository(url)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=url, CMRT_BROKER_URL=redis.url, CMRT_LOG_LEVEL="WARNING",
               CMRT_DISPATCH_WINDOW=str(args.popsize), CMRT_DATA_DIR=str(log_dir),
               PYTHONUNBUFFERED="1")
    procs: list[subprocess.Popen] = []
    instances = math.ceil(workers / args.per_instance)
    threads = workers > args.threads_above
    drivers: list[subprocess.Popen] = []
    try:
        for k in range(instances):
            n = min(args.per_instance, workers - k * args.per_instance)
            with open(log_dir / f"{tag}_worker{k}.log", "wb") as log:
                procs.append(subprocess.Popen(
                    [sys.executable, "-m", "bench.capacity", "worker", "--sleep", str(sleep),
                     "--concurrency", str(n), "--hostname", f"cap{k}@%h",
                     *(["--threads"] if threads else [])],
                    cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                    start_new_session=True))
        workers_procs = list(procs)
        for k in range(args.drivers):
            with open(log_dir / f"{tag}_driver{k}.log", "wb") as log:
                drivers.append(subprocess.Popen(
                    [sys.executable, "-m", "cli.main", "driver"], cwd=driver_root,
                    env={**env, "PYTHONPATH": str(driver_root)}, stdout=log,
                    stderr=subprocess.STDOUT, start_new_session=True))
        procs += drivers
        jobs_n = max(4, math.ceil(args.jobs_per_worker * workers),
                     math.ceil(1.25 * workers / args.popsize))
        spec = parse_spec(_spec(args.popsize, 100_000))
        doc = spec.model_dump(mode="json")
        jobs = [repo.create_job(doc, name=spec.name, family=spec.family_name,
                                task=spec.task_type, seed=j).id for j in range(jobs_n)]
        # warm-up: every job has finished generations (workers forked, simulators... none)
        deadline = time.monotonic() + 120 + 10 * sleep
        need = 3 * args.popsize
        while time.monotonic() < deadline:
            done = _done_by_job(repo)
            if all(done.get(j, 0) >= need for j in jobs):
                break
            for p in procs:
                if p.poll() is not None:
                    raise RuntimeError(f"a process of {tag} exited: see {log_dir}")
            time.sleep(0.5)
        else:
            raise RuntimeError(f"{tag}: jobs did not start within the warm-up; see {log_dir}")
        groups = {"driver": [d.pid for d in drivers], "redis": [redis.proc.pid],
                  "postgres": pg.pids(),
                  "workers": [q for p in workers_procs for q in (p.pid, *_children(p.pid))]}
        c0 = {k: _cpu(v) for k, v in groups.items()}
        load0 = os.getloadavg()[0]
        before, t0 = _done_by_job(repo), time.monotonic()
        time.sleep(args.seconds)
        after, t1 = _done_by_job(repo), time.monotonic()
        cpu = {k: _cpu(v) - c0[k] for k, v in groups.items()}
        pss = [_pss_mb(q) for q in groups["workers"]]
        wall = t1 - t0
        rates = [(after.get(j, 0) - before.get(j, 0)) / wall for j in jobs]
        total = sum(rates)
        n_done = total * wall
        return {
            "workers": workers, "instances": instances, "threads": threads,
            "drivers": args.drivers, "driver_from": str(driver_root), "eval_s": sleep,
            "jobs": jobs_n,
            "popsize": args.popsize, "seconds": wall, "candidates_per_s": total,
            "ideal_per_s": workers / sleep, "busy": total * sleep / workers,
            "job_rate_min": min(rates), "job_rate_max": max(rates),
            "jain": total ** 2 / (len(rates) * sum(r * r for r in rates)) if total else 0.0,
            "cpu_ms_per_candidate": {k: 1e3 * v / max(n_done, 1) for k, v in cpu.items()},
            "cpu_share": {k: v / wall for k, v in cpu.items()},
            "worker_pss_mb": sum(pss) / max(len(pss), 1),
            "load": [load0, os.getloadavg()[0]],
        }
    finally:
        for p in procs:
            _stop(p)
        repo.engine.dispose()
        redis.close()


@dataclass(frozen=True)
class SleepingObjective:
    """An evaluation of `sleep` s of wall time and no CPU that never converges: 1 plus a
    pseudo-random share below 0.01, the same for the same candidate."""

    sleep: float

    def __call__(self, x: Any) -> EvalOutcome:
        time.sleep(self.sleep)
        noise = random.Random(np.asarray(x, dtype=np.float64).tobytes()).random()
        return EvalOutcome(objective=1.0 + 0.01 * noise)


def run_worker(args: argparse.Namespace) -> int:
    """`cmrt worker` whose objective sleeps (see the module docstring)."""
    from cli.main import main as cmrt_main
    from worker import tasks
    from worker.candidates import JobSpecs

    objective = SleepingObjective(args.sleep)
    class Sleeping(JobSpecs):  # every job's objective sleeps
        def get(self, repo, job_id):
            return super().get(repo, job_id)[0], objective

    tasks._cache = Sleeping()  # before Celery forks its pool
    if not args.threads:
        return cmrt_main(["worker", "--concurrency", str(args.concurrency), "--hostname",
                          args.hostname])
    # Threads of one process: the product's worker command with Celery's thread pool, and a
    # database pool with a connection per thread (a prefork process has its own engine).
    from cmrt.settings import get_settings
    from store import SqlRepository, make_engine
    from worker.celery_app import app

    settings = get_settings()
    tasks._repo = SqlRepository(make_engine(settings.database_url, pool_pre_ping=False,
                                            pool_size=args.concurrency, max_overflow=0))
    app.worker_main(["worker", "-Q", settings.queue, "-l", "WARNING", "--without-gossip",
                     "--without-mingle", "-P", "threads", "-c", str(args.concurrency),
                     "-n", args.hostname])
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd")
    w = sub.add_parser("worker", help="(internal) a sleeping worker instance")
    w.add_argument("--sleep", type=float, required=True)
    w.add_argument("--concurrency", type=int, required=True)
    w.add_argument("--hostname", required=True)
    w.add_argument("--threads", action="store_true")
    ap.add_argument("--workers", type=int, nargs="+", default=[8, 32, 128, 256])
    ap.add_argument("--eval", type=float, nargs="+", default=[1.0, 0.1],
                    help="seconds of one evaluation (a sleep)")
    ap.add_argument("--per-instance", type=int, default=32,
                    help="worker processes per `cmrt worker` instance (one host)")
    ap.add_argument("--threads-above", type=int, default=128, metavar="N",
                    help="past N workers, each instance runs threads, not processes (memory)")
    ap.add_argument("--drivers", type=int, default=1, help="`cmrt driver` processes")
    ap.add_argument("--popsize", type=int, default=16)
    ap.add_argument("--jobs-per-worker", type=float, default=0.1)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--driver-from", type=Path, nargs="+", default=[ROOT], metavar="DIR",
                    help="checkouts whose driver code to run (A/B in one run: each point is "
                         "measured with each, in turn, --repeat times); default: this one")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.cmd == "worker":
        return run_worker(args)
    pg = PrivatePostgres(max(args.workers) + PG_SPARE_CONNECTIONS)
    log_dir = Path(tempfile.mkdtemp(prefix="cmrt-capacity-"))
    rows = []
    try:
        for sleep in args.eval:
            for n in args.workers:
                for _ in range(args.repeat):
                    for root in args.driver_from:
                        row = measure(n, sleep, args, pg, log_dir, root.resolve())
                        rows.append(row)
                        if not args.json:
                            _print_row(row, header=len(rows) == 1)
    finally:
        pg.close()
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print(f"logs: {log_dir}")
    return 0


def _print_row(r: dict[str, Any], header: bool) -> None:
    if header:
        print("| eval s | workers (instances x each) | jobs | candidates/s | of ideal "
              "| job min-max /s | Jain | CPU ms/cand. driver | redis | postgres | workers "
              "| CPU share driver | redis | postgres | workers | PSS MB/proc | load "
              "| driver from |")
        print("|" + "---|" * 17)
    c, s = r["cpu_ms_per_candidate"], r["cpu_share"]
    how = f"{r['instances']} x {r['workers'] // r['instances']} " + (
        "threads" if r["threads"] else "proc.")
    print(f"| {r['eval_s']:g} | {r['workers']} ({how}) | {r['jobs']} | "
          f"{r['candidates_per_s']:.1f} | {r['busy']:.0%} | {r['job_rate_min']:.2f}-"
          f"{r['job_rate_max']:.2f} | {r['jain']:.3f} | {c['driver']:.2f} | {c['redis']:.2f} | "
          f"{c['postgres']:.2f} | {c['workers']:.2f} | {s['driver']:.0%} | {s['redis']:.0%} | "
          f"{s['postgres']:.0%} | {s['workers']:.0%} | {r['worker_pss_mb']:.0f} | "
          f"{r['load'][0]:.1f}-{r['load'][1]:.1f} | {Path(r['driver_from']).name} |",
          flush=True)


if __name__ == "__main__":
    sys.exit(main())
