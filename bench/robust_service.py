"""A robust job against a nominal one on Celery workers: candidates and clips per second.

    .venv/bin/python bench/robust_service.py [--spec bench/data/robust/domino_robust.yaml]
        [--candidates 20] [--concurrency 2] [--repeat 3] [--json]

Starts one `cmrt worker --concurrency N` on a private queue (Redis at CMRT_TEST_REDIS, default
redis://127.0.0.1:6379; a scratch SQLite store), then drives two jobs through the job driver's
own `CeleryExecutor`: the spec without its robust block (the nominal job) and the spec as it is
(K variants per candidate), each `--candidates` candidates (popsize 10), after one untimed
nominal job (the workers' simulators built), `--repeat` times alternating. Prints, per job
(the run of median wall time), the wall seconds, candidates and clips per second, and how many
clips each worker process evaluated (the variants spread over the workers). Both jobs include
the final evaluation (2 candidates, 2 K clips). Timings on a shared machine are noisy: quote the
ratio.
"""

from __future__ import annotations

import argparse
import collections
import copy
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from proc_helpers import stop_group  # noqa: E402

from cmrt.settings import Settings  # noqa: E402
from sim.spec import load_spec, parse_canonical  # noqa: E402
from store import open_repository  # noqa: E402
from worker.celery_app import make_celery  # noqa: E402
from worker.driver import JobDriver  # noqa: E402
from worker.executors import CeleryExecutor  # noqa: E402

REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")


def _job(repo, settings, doc: dict) -> dict:
    canonical = parse_canonical(doc)
    job = repo.create_job(canonical.document, name=canonical.spec.name,
                          family=canonical.spec.family_name, task=canonical.spec.task_type,
                          seed=1)
    ex = CeleryExecutor(settings, make_celery(settings.broker_url, settings.broker_url,
                                              settings))
    t0 = time.perf_counter()
    status = JobDriver(repo, job.id, ex, settings).run()
    wall = time.perf_counter() - t0
    rows = [r for g in range(-1, repo.get_job(job.id).iterations)
            for r in repo.evaluations(job.id, g)]
    per_worker = collections.Counter((r.details or {}).get("worker", "?") for r in rows)
    j = repo.get_job(job.id)
    return {"status": status, "wall_seconds": wall, "candidates": j.evaluations + 2,
            "clips": len(rows), "candidates_per_s": (j.evaluations + 2) / wall,
            "clips_per_s": len(rows) / wall, "best_objective": j.best_objective,
            "clips_per_worker_process": dict(sorted(per_worker.items()))}


def _median(runs: list[dict]) -> dict:
    """The run of median wall time."""
    return sorted(runs, key=lambda r: r["wall_seconds"])[len(runs) // 2]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--spec", default=str(ROOT / "bench/data/robust/domino_robust.yaml"))
    p.add_argument("--candidates", type=int, default=20)
    p.add_argument("--concurrency", type=int, default=2)
    p.add_argument("--repeat", type=int, default=3, help="timed runs of each job, alternating")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    spec = load_spec(args.spec)
    robust = spec.model_dump(mode="json")
    robust["optimize"].update(popsize=10, max_evaluations=args.candidates, min_evaluations=0)
    robust["optimize"].pop("threshold", None)
    nominal = copy.deepcopy(robust)
    nominal["optimize"].pop("robust")
    tmp = Path(tempfile.mkdtemp(prefix="robust_service_"))
    broker = f"{REDIS}/{9 + uuid.uuid4().int % 6}"
    db = f"sqlite:///{tmp}/b.db"
    settings = Settings(data_dir=tmp, database_url=db, broker_url=broker,
                        workers=args.concurrency, queue=f"q{uuid.uuid4().hex[:8]}")
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=db, CMRT_BROKER_URL=broker, CMRT_QUEUE=settings.queue)
    worker = subprocess.Popen([str(ROOT / ".venv/bin/cmrt"), "worker", "--concurrency",
                               str(args.concurrency), "--hostname",
                               f"bench-{uuid.uuid4().hex[:6]}@%h"], env=env,
                              stdout=(tmp / "worker.log").open("wb"),
                              stderr=subprocess.STDOUT, start_new_session=True)
    try:
        repo = open_repository(db)
        _job(repo, settings, nominal)  # warm-up: the workers' simulators built, not timed
        runs: dict[str, list[dict]] = {"nominal": [], "robust": []}
        for _ in range(args.repeat):  # alternating, so that both see the same machine load
            runs["nominal"].append(_job(repo, settings, nominal))
            runs["robust"].append(_job(repo, settings, robust))
        out = {"spec": spec.name, "concurrency": args.concurrency,
               "samples": spec.optimize.robust.samples, "repeat": args.repeat,
               **{k: _median(v) for k, v in runs.items()}}
    finally:
        stop_group(worker)
    n, r = out["nominal"], out["robust"]
    out["candidates_per_s_ratio"] = r["candidates_per_s"] / n["candidates_per_s"]
    out["clips_per_s_ratio"] = r["clips_per_s"] / n["clips_per_s"]
    if args.json:
        print(json.dumps(out))
        return 0
    for name in ("nominal", "robust"):
        d = out[name]
        print(f"{name:>8}: {d['candidates']} candidates, {d['clips']} clips in "
              f"{d['wall_seconds']:.1f} s: {d['candidates_per_s']:.2f} candidates/s, "
              f"{d['clips_per_s']:.2f} clips/s; clips per worker process "
              f"{d['clips_per_worker_process']}")
    print(f"robust / nominal: candidates/s x{out['candidates_per_s_ratio']:.3f}, clips/s "
          f"x{out['clips_per_s_ratio']:.3f} (K = {out['samples']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
