"""A family on the deployed topology equals the command line's, and survives a killed worker.

    .venv/bin/python bench/family_service.py [--spec examples/fast_bend.yaml]
        [--param clip.duration] [--values 0.3 0.35 0.4 0.45 0.5] [--leave-out 0.4] [--k 2]
        [--optimize max_evaluations=60 min_evaluations=20 window=4] [--workers 2]
        [--kill-after 20] [--json]

1. `cmrt family run` on the embedded default (a local pool of --workers processes).
2. The same request through `cmrt family submit` to `cmrt serve` on PostgreSQL (a database of
   its own on the machine's server, CMRT_BENCH_PG) and Celery on a private redis-server, with
   --workers `cmrt worker --concurrency 1` processes; --kill-after s after the submission one
   worker's process group is killed with SIGKILL mid-family and a new worker started. A
   worker killed outright leaves its reserved task unacknowledged until Redis' visibility
   timeout; the job's driver re-sends a candidate unresolved for CMRT_STALL_TIMEOUT (default
   CMRT_EVAL_TIME_LIMIT + 60 = 660 s). The service here runs with a 30 s time limit and a 45 s
   stall timeout (--stall), so the recovery shows within the run.
3. The two reports compared: every member's parameters and objective, every run's
   evaluations, and the checks (Table 2 rows, probes, reconstruction errors) must be equal;
   the service's evaluations repeated after the kill (attempts above one) are counted, and
   any candidate left unresolved ("lost") would have kept the family from finishing.
Prints the wall times and the comparison; exit 1 if the families differ.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import sqlalchemy as sa

ROOT = Path(__file__).resolve().parents[1]
CMRT = ROOT / ".venv" / "bin" / "cmrt"
PG_ADMIN = os.environ.get("CMRT_BENCH_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(argv: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
    with open(log, "w") as f:  # the child keeps its own descriptor
        return subprocess.Popen(argv, env=env, stdout=f, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _stop(p: subprocess.Popen, sig: int = signal.SIGTERM) -> None:
    if p.poll() is None:
        os.killpg(p.pid, sig)
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def _request_args(args: argparse.Namespace) -> list[str]:
    out = [args.spec, "--param", args.param, "--values", *map(str, args.values),
           "--strategy", args.strategy, "--from", args.start_from, "--k", str(args.k),
           "--seed", str(args.seed)]
    if args.leave_out:
        out += ["--leave-out", *map(str, args.leave_out)]
    if args.optimize:
        out += ["--optimize", *args.optimize]
    if args.warm:
        out += ["--warm", *args.warm]
    return out


def _compare(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    diffs = []
    ma = {m["value"]: m for m in a["members"]}
    mb = {m["value"]: m for m in b["members"]}
    if sorted(ma) != sorted(mb):
        diffs.append(f"member values {sorted(ma)} != {sorted(mb)}")
    for v in sorted(set(ma) & set(mb)):
        for key in ("params", "objective", "evaluations", "run"):
            if ma[v][key] != mb[v][key]:
                diffs.append(f"member {v}: {key} differs")
    ra = {r["id"]: r for r in a["runs"]}
    rb = {r["id"]: r for r in b["runs"]}
    for rid in sorted(set(ra) | set(rb)):
        if rid not in ra or rid not in rb:
            diffs.append(f"run {rid} only on one side")
        elif ra[rid]["evaluations"] != rb[rid]["evaluations"]:
            diffs.append(f"run {rid}: evaluations {ra[rid]['evaluations']} != "
                         f"{rb[rid]['evaluations']}")
    if a["checks"] != b["checks"]:
        diffs.append("checks differ")
    return diffs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spec", default=str(ROOT / "examples" / "fast_bend.yaml"))
    ap.add_argument("--param", default="clip.duration")
    ap.add_argument("--values", type=float, nargs="+", default=[0.3, 0.35, 0.4, 0.45, 0.5])
    ap.add_argument("--strategy", default="continuation")
    ap.add_argument("--from", dest="start_from", default="both")
    ap.add_argument("--leave-out", type=float, nargs="*", default=[0.4])
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--optimize", nargs="*",
                    default=["max_evaluations=60", "min_evaluations=20", "window=4",
                             "threshold=none"])
    ap.add_argument("--warm", nargs="*", default=["max_evaluations=24", "window=3"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--kill-after", type=float, default=20.0)
    ap.add_argument("--stall", type=float, default=45.0,
                    help="CMRT_STALL_TIMEOUT of the service, s (re-send unresolved candidates)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="cmrt-family-bench-"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    req = _request_args(args)
    out: dict[str, Any] = {}

    t0 = time.perf_counter()
    subprocess.run([str(CMRT), "family", "run", *req, "--workers", str(args.workers),
                    "--out", str(work / "embedded.json")], env=env, check=True,
                   capture_output=True, text=True)
    out["embedded_wall_s"] = time.perf_counter() - t0
    embedded = json.loads((work / "embedded.json").read_text())

    admin = sa.create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    db = f"cmrt_family_bench_{os.getpid()}"
    with admin.connect() as c:
        c.execute(sa.text(f'drop database if exists "{db}"'))
        c.execute(sa.text(f'create database "{db}"'))
    redis_port, api_port = _port(), _port()
    procs: list[subprocess.Popen] = []
    try:
        redis = _start(["redis-server", "--port", str(redis_port), "--bind", "127.0.0.1",
                        "--save", "", "--appendonly", "no"], env, work / "redis.log")
        procs.append(redis)
        senv = {**env, "CMRT_DATABASE_URL": sa.engine.make_url(PG_ADMIN).set(database=db)
                .render_as_string(hide_password=False),
                "CMRT_BROKER_URL": f"redis://127.0.0.1:{redis_port}/0",
                "CMRT_DATA_DIR": str(work), "CMRT_SCAN_INTERVAL": "0.5",
                "CMRT_EVAL_TIME_LIMIT": "30", "CMRT_STALL_TIMEOUT": str(args.stall),
                "CMRT_VISIBILITY_TIMEOUT": "300",
                "CMRT_URL": f"http://127.0.0.1:{api_port}"}
        procs.append(_start([str(CMRT), "serve", "--port", str(api_port)], senv,
                            work / "serve.log"))
        api = senv["CMRT_URL"]
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(api + "/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("cmrt serve did not start: " + (work / "serve.log")
                                   .read_text()[-2000:])
            time.sleep(0.3)
        workers = [_start([str(CMRT), "worker", "--concurrency", "1"], senv,
                          work / f"worker{i}.log") for i in range(args.workers)]
        procs += workers
        t0 = time.perf_counter()
        sub = subprocess.run([str(CMRT), "family", "submit", *req, "--json"], env=senv,
                             check=True, capture_output=True, text=True)
        fid = json.loads(sub.stdout)["id"]
        killed = False
        while True:
            body = httpx.get(f"{api}/families/{fid}", timeout=30).json()
            if body["status"] != "running":
                break
            if not killed and time.perf_counter() - t0 >= args.kill_after:
                _stop(workers[0], signal.SIGKILL)
                procs.append(_start([str(CMRT), "worker", "--concurrency", "1"], senv,
                                    work / "worker_new.log"))
                killed = True
                out["killed_at_s"] = time.perf_counter() - t0
                out["runs_done_at_kill"] = body["progress"]["done"]
            time.sleep(0.5)
        out["service_wall_s"] = time.perf_counter() - t0
        out["service_status"] = body["status"]
        report = httpx.get(f"{api}/families/{fid}", timeout=30).json()
        repeated = attempts = 0
        for run in report["runs"]:
            gens = httpx.get(f"{api}/jobs/{run['job_id']}/evaluations",
                             timeout=30).json()["generations"]
            repeated += sum(g["repeated"] for g in gens)
            attempts += sum(g["attempts"] for g in gens)
        out["service_attempts"] = attempts
        out["service_repeated"] = repeated
        service = {"members": report["members"], "checks": report["checks"],
                   "runs": [{"id": r["id"], "evaluations": r["evaluations"]}
                            for r in report["runs"]]}
        diffs = _compare(embedded, service)
        out["differences"] = diffs
    finally:
        for p in reversed(procs):
            _stop(p)
        with admin.connect() as c:
            c.execute(sa.text(f'drop database if exists "{db}" with (force)'))
        admin.dispose()
    with open("/proc/loadavg") as f:
        out["load"] = " ".join(f.read().split()[:3])
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"embedded: {out['embedded_wall_s']:.0f} s; service (Celery, {args.workers} "
              f"workers, PostgreSQL): {out['service_wall_s']:.0f} s, {out['service_status']}; "
              f"worker killed at {out.get('killed_at_s', float('nan')):.0f} s with "
              f"{out.get('runs_done_at_kill')} runs done; {out['service_attempts']} attempts, "
              f"{out['service_repeated']} repeated; load {out['load']}")
        print("identical members, runs and checks" if not out["differences"]
              else "DIFFERENCES: " + "; ".join(out["differences"]))
    shutil.rmtree(work, ignore_errors=True)
    return 0 if not out["differences"] and out["service_status"] == "done" else 1


if __name__ == "__main__":
    raise SystemExit(main())
