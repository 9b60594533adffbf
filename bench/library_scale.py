"""The CMRT library at scale: query latency with 10,000 CMRTs in 200 families.

    .venv/bin/python bench/library_scale.py [--backend sqlite postgresql] [--families 200]
        [--per-family 50] [--requests 400] [--pages 3] [--client http.client httpx]
        [--cmrt EXE [EXE ...]] [--rounds 1] [--json]

For each backend, a fresh database is filled through the store (`Repository.add_cmrt`, one
entry per call as the job driver adds them): `--families` families of `--per-family` domino
CMRTs each along the wall's mass (the CMRT parameters, knots, values and curve of a spec-valid
spline; objectives made up, since only the reads are measured). Then `cmrt serve` runs on it
(loopback, drivers idle) and a client on this machine asks, one request at a time, over random
families and masses:
  * `GET /cmrts?family=F&mass=M&tolerance=T` (nearest members within +-T kg),
  * `GET /cmrts/interpolate?family=F&mass=M` (the interpolated CMRT between the two nearest),
  * `GET /cmrts/families` (the library's families and their sizes, the library page's list),
  * `GET /health` (a database ping: the floor the HTTP stack and the client set),
and reports each one's p50 / p99 / max in ms, for each `--client`: `http.client` (the standard
library's, one kept-alive connection: a few hundredths of a ms of its own per request, so the
figures are the server's and the loopback's) and `httpx` (what `cmrt.client` uses: about 1 ms
of its own per request on this machine, which is in its figures). `--cmrt A B` serves the same
database with each executable in turn (another checkout's `.venv/bin/cmrt`: before and after
a change in one run), `--rounds` times alternating; then the library page
(`/dashboard/library?family=F`) in Debian's Chromium, `--pages` loads: ms from navigation
start until the page says it has drawn (table, overlay, interpolation and bases shown).
PostgreSQL: the machine's server (CMRT_BENCH_PG, default postgresql+psycopg://postgres@
127.0.0.1:5432/test), with a database of its own made and dropped by the script.
No assertions: figures go to docs/benchmarks.md with the machine's load.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import httpx
import numpy as np
import sqlalchemy as sa
import yaml

from optim.spline import decode, sample_curve
from sim.spec import parse_spec
from store import CmrtEntry, open_repository

ROOT = Path(__file__).resolve().parents[1]
CMRT = ROOT / ".venv" / "bin" / "cmrt"
PG_ADMIN = os.environ.get("CMRT_BENCH_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
#: The wall masses of a family span 30-150 kg, as the paper's domino family does.
MASS_LO, MASS_HI = 30.0, 150.0
#: The query's tolerance, kg: about one member spacing either side.
TOLERANCE = 5.0


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _entries(families: int, per_family: int, seed: int) -> list[CmrtEntry]:
    base = yaml.safe_load((ROOT / "examples" / "domino.yaml").read_text())
    rng = np.random.default_rng(seed)
    out = []
    masses = np.linspace(MASS_LO, MASS_HI, per_family)
    for f in range(families):
        family = f"domino_{f:03d}"
        for m in masses:
            doc = {**base, "family": family, "task": {**base["task"], "mass": float(m)}}
            spec = parse_spec(doc)
            params = rng.uniform(0.2, 0.8, spec.cmrt_dimension)
            spline = decode(spec, params)
            out.append(CmrtEntry(
                family=family, character=spec.character.model_dump(mode="json"),
                task_parameters=spec.task_parameters(), preparation=spec.clip.preparation,
                duration=spec.clip.duration, decay=spec.clip.decay,
                params=[float(v) for v in params],
                knots=[float(v) for v in spline.knot_times],
                values=[float(v) for v in spline.values], curve=sample_curve(spline),
                objective=float(rng.uniform(1, 3)), objective_without=float(rng.uniform(3, 4)),
                fell=False, fell_without=False, spec=spec.model_dump(mode="json"),
            ))  # fmt: skip
    return out


def _fill(url: str, entries: list[CmrtEntry]) -> float:
    repo = open_repository(url)
    t0 = time.perf_counter()
    for e in entries:
        repo.add_cmrt(e)
    repo.engine.dispose()
    return time.perf_counter() - t0


def _stats(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max()), "mean": float(a.mean()), "n": len(ms)}


def _serve(url: str, data: Path, cmrt: Path = CMRT) -> tuple[subprocess.Popen, str]:
    port = _port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATA_DIR=str(data), CMRT_DATABASE_URL=url, CMRT_WORKERS="1",
               CMRT_LOG_LEVEL="WARNING")
    with open(data / "serve.log", "w") as log:  # the child keeps its own descriptor
        proc = subprocess.Popen(
            [str(cmrt), "serve", "--host", "127.0.0.1", "--port", str(port)], env=env,
            stdout=subprocess.DEVNULL, stderr=log, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(base + "/health", timeout=2).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            time.sleep(0.2)
    raise RuntimeError(f"cmrt serve did not start; see {data / 'serve.log'}")


class _StdlibClient:
    """GET over one kept-alive `http.client` connection (the least client cost in Python)."""

    def __init__(self, base: str) -> None:
        host, _, port = base.removeprefix("http://").partition(":")
        self.conn = http.client.HTTPConnection(host, int(port), timeout=30)

    def get(self, path: str, params: dict[str, Any]) -> tuple[int, bytes]:
        self.conn.request("GET", f"{path}?{urlencode(params)}" if params else path)
        r = self.conn.getresponse()
        return r.status, r.read()

    def close(self) -> None:
        self.conn.close()


class _HttpxClient:
    def __init__(self, base: str) -> None:
        self.c = httpx.Client(base_url=base, timeout=30)

    def get(self, path: str, params: dict[str, Any]) -> tuple[int, bytes]:
        r = self.c.get(path, params=params)
        return r.status_code, r.content

    def close(self) -> None:
        self.c.close()


CLIENTS = {"http.client": _StdlibClient, "httpx": _HttpxClient}


def _verified_points(families: int, n: int, seed: int) -> list[dict[str, Any]]:
    """The queries answered with `verify=true` (each simulated once, then kept)."""
    rng = random.Random(seed + 10_000)
    return [{"family": f"domino_{rng.randrange(families):03d}",
             "mass": round(rng.uniform(MASS_LO, MASS_HI), 2), "verify": "true"}
            for _ in range(n)]


def _first_verified(base: str, points: list[dict[str, Any]]) -> list[float]:
    """Milliseconds of each point's verified answer (the first one simulates it)."""
    c = CLIENTS["httpx"](base)
    out = []
    try:
        for q in points:
            t0 = time.perf_counter()
            status, body = c.get("/cmrts/interpolate", q)
            if status != 200:
                raise RuntimeError(f"verify {q}: {status} {body[:200]!r}")
            out.append((time.perf_counter() - t0) * 1000)
    finally:
        c.close()
    return out


def _cpu_clock(pid: int) -> int:
    """The clock id of process `pid`'s CPU time, all its threads (Linux: CPUCLOCK_SCHED of a
    process, nanosecond resolution), read with `time.clock_gettime` from outside it."""
    return ((~pid) << 3) | 2


def _requests(base: str, families: int, n: int, seed: int, client: str = "httpx",
              verified: list[dict[str, Any]] | None = None, pid: int | None = None
              ) -> dict[str, Any]:
    """Each request kind's latencies (ms) and, given the server's `pid`, the server process's
    CPU per request (ms, under "<kind> cpu"): what a busy machine does not inflate."""
    rng = random.Random(seed)
    out: dict[str, list[float]] = {"find": [], "interpolate": [], "verified": [],
                                   "families": [], "health": []}
    cpu: dict[str, list[float]] = {k: [] for k in out}
    clock = None if pid is None else _cpu_clock(pid)
    c = CLIENTS[client](base)
    try:
        for i in range(n + 20):  # the first 20 warm the server up and are not counted
            fam = f"domino_{rng.randrange(families):03d}"
            mass = round(rng.uniform(MASS_LO, MASS_HI), 2)
            kept = [("verified", "/cmrts/interpolate", rng.choice(verified))] if verified else []
            for name, path, q in (
                ("find", "/cmrts", {"family": fam, "mass": mass, "tolerance": TOLERANCE}),
                ("interpolate", "/cmrts/interpolate", {"family": fam, "mass": mass}),
                *kept,  # a verified answer the library kept: no simulation
                ("families", "/cmrts/families", {}),
                ("health", "/health", {}),  # the HTTP stack's floor, a database ping
            ):
                c0 = 0.0 if clock is None else time.clock_gettime(clock)
                t0 = time.perf_counter()
                status, body = c.get(path, q)
                dt = (time.perf_counter() - t0) * 1000
                c1 = 0.0 if clock is None else time.clock_gettime(clock)
                if status != 200:
                    raise RuntimeError(f"{path} {q}: {status} {body[:200]!r}")
                if i >= 20:
                    out[name].append(dt)
                    if clock is not None:
                        cpu[name].append((c1 - c0) * 1000)
    finally:
        c.close()
    out.update((f"{k} cpu", v) for k, v in cpu.items())
    return out


def _pages(base: str, families: int, loads: int) -> list[float]:
    from playwright.sync_api import sync_playwright

    drawn = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
        for i in range(loads + 1):
            ctx = browser.new_context(viewport={"width": 1280, "height": 900})
            page = ctx.new_page()
            page.goto(f"{base}/dashboard/library?family=domino_{(7 * i) % families:03d}")
            page.wait_for_selector("body[data-state='loaded']", timeout=120_000)
            ms = page.evaluate("performance.now()")
            if i:  # the first load warms the server's caches and Chromium's
                drawn.append(float(ms))
            ctx.close()
        browser.close()
    return drawn


def _label(exe: Path) -> str:
    """`checkout@commit` of a `cmrt` executable (`<checkout>/.venv/bin/cmrt`)."""
    root = Path(exe).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "-uno"],
                               capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return root.name
    return f"{root.name}@{commit}{'+' if dirty else ''}"


def _pg_url(name: str) -> str:
    u = sa.engine.make_url(PG_ADMIN)
    return u.set(database=name).render_as_string(hide_password=False)


def run_backend(backend: str, args: argparse.Namespace, entries: list[CmrtEntry]) -> dict:
    data = Path(tempfile.mkdtemp(prefix=f"cmrt-libscale-{backend}-"))
    admin = None
    name = f"cmrt_libscale_{os.getpid()}"
    if backend == "sqlite":
        url = f"sqlite:///{data}/cmrt.db"
    else:
        admin = sa.create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'drop database if exists "{name}"'))
            c.execute(sa.text(f'create database "{name}"'))
        url = _pg_url(name)
    proc = None
    try:
        fill_s = _fill(url, entries)
        samples: dict[tuple[str, str], dict[str, list[float]]] = {}
        pages: list[float] = []
        points = _verified_points(args.families, args.verified, args.seed)
        first: list[float] = []
        for rnd in range(args.rounds):
            for exe in args.cmrt:
                proc, base = _serve(url, data, exe)
                if points and not first:
                    first = _first_verified(base, points)
                for client in args.client:
                    got = _requests(base, args.families, args.requests, args.seed + rnd, client,
                                    points, proc.pid)
                    into = samples.setdefault((_label(exe), client), {})
                    for k, v in got.items():
                        into.setdefault(k, []).extend(v)
                if args.pages and rnd == 0 and exe == args.cmrt[-1]:
                    pages = _pages(base, args.families, args.pages)
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(timeout=30)
                proc = None
        lat = [{"server": srv, "client": cl, **{k: _stats(v) for k, v in by.items() if v}}
               for (srv, cl), by in samples.items()]
        return {"backend": backend, "cmrts": len(entries), "fill_seconds": fill_s,
                "latency_ms": lat, "page_drawn_ms": pages, "first_verified_ms": first}
    finally:
        if proc is not None:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
        if admin is not None:
            with admin.connect() as c:
                c.execute(sa.text(f'drop database if exists "{name}" with (force)'))
            admin.dispose()
        shutil.rmtree(data, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", nargs="+", default=["sqlite", "postgresql"],
                    choices=["sqlite", "postgresql"])
    ap.add_argument("--families", type=int, default=200)
    ap.add_argument("--per-family", type=int, default=50)
    ap.add_argument("--requests", type=int, default=400)
    ap.add_argument("--pages", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--client", nargs="+", default=list(CLIENTS), choices=list(CLIENTS))
    ap.add_argument("--cmrt", nargs="+", type=Path, default=[CMRT],
                    help="cmrt executables to serve with, in turn (default: this checkout's)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="times each executable serves, alternating (samples pooled)")
    ap.add_argument("--verified", type=int, default=5,
                    help="queries answered with verify=true: each simulated once (timed "
                         "apart), then asked again among the timed requests (kept answers)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    entries = _entries(args.families, args.per_family, args.seed)
    results = [run_backend(b, args, entries) for b in args.backend]
    with open("/proc/loadavg") as f:
        load = " ".join(f.read().split()[:3])
    if args.json:
        print(json.dumps({"load": load, "results": results}, indent=1))
        return
    print(f"{len(entries)} CMRTs in {args.families} families; load average {load}")
    print("| backend | server | client | request | p50 ms | p99 ms | max ms | server CPU ms "
          "(mean) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        for row in r["latency_ms"]:
            for name in ("find", "interpolate", "verified", "families", "health"):
                s = row.get(name)
                if s is None:
                    continue
                c = row.get(f"{name} cpu")
                cpu = "" if c is None else f"{c['mean']:.2f}"
                print(f"| {r['backend']} | {row['server']} | {row['client']} | {name} | "
                      f"{s['p50']:.2f} | {s['p99']:.2f} | {s['max']:.1f} | {cpu} |")
        if r["first_verified_ms"]:
            ms = ", ".join(f"{v:.0f}" for v in r["first_verified_ms"])
            print(f"| {r['backend']} | | | first verified answer (ms) | {ms} | | | |")
        if r["page_drawn_ms"]:
            ms = ", ".join(f"{v:.0f}" for v in r["page_drawn_ms"])
            print(f"| {r['backend']} | | | library page drawn (ms) | {ms} | | | |")
        print(f"({r['backend']}: filled in {r['fill_seconds']:.0f} s)")

if __name__ == "__main__":
    main()
