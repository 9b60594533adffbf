"""A small job next to a huge one, and cancelling the huge one mid-generation.

    .venv/bin/python bench/fair_share.py [--mode local|celery] [--repeat 3] [--workers 2]
        [--window N] [--serve "CMD"] [--json]

Starts the service as a user would (`cmrt serve` on a free port; `--mode celery` also a
`cmrt worker --concurrency N` and a private redis-server), on a fresh SQLite database, then
`--repeat` times:
  1. the small job alone (a 0.9 s bend clip, popsize 4, one generation + the final pair):
     seconds from POST /jobs to its end;
  2. the huge job (popsize 60, 20 s clips, issue 11's shape with max_evaluations cut under the
     budget ceiling), and once its first candidates run, the small job again: seconds from POST
     to its end, next to the huge job's whole-generation time estimate;
  3. that huge job cancelled, a second one started and, once its first candidates run,
     cancelled mid-generation: seconds until POST /jobs/{id}/cancel answers, and until
     GET /jobs/{id} says `cancelled`; then the seconds until the evaluation processes are idle
     again (no candidate of it still running: CPU of the pool's processes back to ~0).
`--serve` replaces the server command (e.g. an older checkout's
`/path/.venv/bin/python -m service --port {port}`), to measure the same figures before a
change. No assertions: a shared 2-core machine is noisy.
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
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
TERMINAL = ("converged", "stopped", "failed", "cancelled")


def small_spec(k: int) -> dict:
    return {"name": f"small_{k}", "family": "bend",
            "clip": {"preparation": 0.3, "duration": 0.3, "decay": 0.3},
            "task": {"type": "pose_change", "target": {"waist": -40}},
            "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0}}


def huge_spec(k: int) -> dict:
    return {"name": f"huge_{k}", "family": "bend",
            "clip": {"preparation": 1.0, "duration": 10.0, "decay": 9.0},
            "task": {"type": "pose_change",
                     "target": {"waist": -90, "shoulder_r": 90, "shoulder_l": 90}},
            "optimize": {"popsize": 60, "max_evaluations": 2400, "min_evaluations": 2400}}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def submit(api: str, spec: dict) -> str:
    r = httpx.post(f"{api}/jobs", json={"spec": spec}, timeout=30)
    r.raise_for_status()
    return r.json()["id"]


def wait_status(api: str, job: str, statuses=TERMINAL, timeout: float = 600.0) -> dict:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        j = httpx.get(f"{api}/jobs/{job}", timeout=30).json()
        if j["status"] in statuses:
            return j
        time.sleep(0.02)
    raise TimeoutError(f"job {job} not in {statuses} after {timeout} s")


def started(api: str, job: str) -> int:
    gens = httpx.get(f"{api}/jobs/{job}/evaluations", timeout=30).json()["generations"]
    return sum(g["attempts"] for g in gens)


def children_cpu(pid: int) -> float:
    """CPU seconds so far of every descendant of `pid` (Linux /proc)."""
    total = 0.0
    tick = os.sysconf("SC_CLK_TCK")
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            stat = (p / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        ppid = int(stat[1])
        # walk up to see if pid is an ancestor
        anc, hops = ppid, 0
        while anc > 1 and anc != pid and hops < 10:
            try:
                anc = int((Path("/proc") / str(anc) / "stat").read_text().rsplit(")", 1)[1]
                          .split()[1])
            except OSError:
                break
            hops += 1
        if anc == pid or ppid == pid:
            total += (int(stat[11]) + int(stat[12])) / tick
    return total


def idle_after(pid: int, t0: float, timeout: float = 60.0) -> float:
    """Seconds from `t0` until the descendants of `pid` use < 10 % of a core over 0.5 s."""
    while time.monotonic() - t0 < timeout:
        a = children_cpu(pid)
        time.sleep(0.5)
        if children_cpu(pid) - a < 0.05:
            return time.monotonic() - t0 - 0.5
    return float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("local", "celery"), default="local")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2, help="evaluation processes")
    ap.add_argument("--serve", default=None,
                    help="server command, {port} is replaced (default: cmrt serve --port {port})")
    ap.add_argument("--window", type=int, default=None,
                    help="Celery: CMRT_DISPATCH_WINDOW of the server (default: the setting's)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    scratch = Path(tempfile.mkdtemp(prefix="cmrt-fair-"))
    port = free_port()
    api = f"http://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=f"sqlite:///{scratch}/bench.db", CMRT_WORKERS=str(args.workers),
               CMRT_API_PORT=str(port), PYTHONUNBUFFERED="1")
    if args.window is not None:
        env["CMRT_DISPATCH_WINDOW"] = str(args.window)
    procs: list[subprocess.Popen] = []
    try:
        if args.mode == "celery":
            rport = free_port()
            procs.append(subprocess.Popen(["redis-server", "--port", str(rport), "--save", "",
                                           "--appendonly", "no"], cwd=scratch,
                                          stdout=subprocess.DEVNULL, start_new_session=True))
            env["CMRT_BROKER_URL"] = f"redis://127.0.0.1:{rport}/0"
        serve = (args.serve or f"{ROOT}/.venv/bin/cmrt serve --port {{port}}").format(port=port)
        procs.append(subprocess.Popen(["bash", "-c", f"exec {serve}"], cwd=scratch, env=env,
                                      stdout=(scratch / "serve.log").open("wb"),
                                      stderr=subprocess.STDOUT, start_new_session=True))
        server = procs[-1]
        pool_owner = server.pid
        if args.mode == "celery":
            procs.append(subprocess.Popen(
                [f"{ROOT}/.venv/bin/python", "-m", "worker", "--concurrency", str(args.workers),
                 "--loglevel", "WARNING"], cwd=ROOT, env=env,
                stdout=(scratch / "worker.log").open("wb"), stderr=subprocess.STDOUT,
                start_new_session=True))
            pool_owner = procs[-1].pid
        t0 = time.monotonic()
        while True:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{api}/health", timeout=2).status_code == 200:
                    break
            if time.monotonic() - t0 > 120 or server.poll() is not None:
                raise RuntimeError((scratch / "serve.log").read_text()[-2000:])
            time.sleep(0.2)
        wait_status(api, submit(api, small_spec(-1)))  # warm-up: processes, simulators
        rows = []
        for k in range(args.repeat):
            t = time.monotonic()
            wait_status(api, submit(api, small_spec(2 * k)))
            alone = time.monotonic() - t
            huge = submit(api, huge_spec(k))
            while started(api, huge) < args.workers:
                time.sleep(0.05)
            time.sleep(1.0)  # mid-candidate
            t = time.monotonic()
            wait_status(api, submit(api, small_spec(2 * k + 1)))
            beside = time.monotonic() - t
            httpx.post(f"{api}/jobs/{huge}/cancel", timeout=60)
            wait_status(api, huge, ("cancelled",))
            huge = submit(api, huge_spec(100 + k))  # a fresh one, cancelled mid-generation
            while started(api, huge) < args.workers:
                time.sleep(0.05)
            time.sleep(1.0)  # mid-candidate
            t = time.monotonic()
            r = httpx.post(f"{api}/jobs/{huge}/cancel", timeout=60)
            answered = time.monotonic() - t
            wait_status(api, huge, ("cancelled",))
            cancelled = time.monotonic() - t
            idle = idle_after(pool_owner, t)
            rows.append({"small_alone_s": alone, "small_beside_huge_s": beside,
                         "cancel_answered_s": answered, "cancel_status": r.status_code,
                         "cancelled_after_s": cancelled, "pool_idle_after_s": idle})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
        med = {key: statistics.median(r[key] for r in rows) for key in rows[0]}
        out = {"mode": args.mode, "workers": args.workers, "repeat": args.repeat,
               "median": med, "runs": rows}
        print(json.dumps(out, indent=None if args.json else 2))
        return 0
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(10)
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
