"""Where a `/health` request's time goes: the app in process, its parts, and the server.

    .venv/bin/python bench/http_floor.py [--requests 2000] [--database URL] [--json]
    OTHER_CHECKOUT/.venv/bin/python bench/http_floor.py   # that checkout's app, same bench

On a fresh SQLite database (or `--database`), drivers off:
  * the app alone: `GET /health` as an ASGI call in this process (no socket, no server): the
    middlewares, the edge (`service.security.HttpEdge`), routing, dependencies, the endpoint
    and its database ping, the JSON answer;
  * its parts alone: `allowed_methods` (probing every route with every method: what the edge
    did for every request before it remembered each path's set), the ping (`Repository.ping`)
    and the jobs listing `/health` used before (`list_jobs(limit=1)`: a count and a page);
  * through uvicorn over loopback with each HTTP implementation and event loop
    (`h11` + `asyncio`, `httptools` + `uvloop`), the client one kept-alive `http.client`
    connection (a few hundredths of a ms of its own).
p50 and p99 in ms of `--requests` calls each, after 200 unmeasured ones. No assertions: the
figures go to docs/benchmarks.md ("The HTTP floor") with the load.
"""

from __future__ import annotations

import argparse
import asyncio
import http.client
import importlib.util
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np

WARM = 200


def _stats(seconds: list[float]) -> dict[str, float]:
    a = np.asarray(seconds) * 1e3
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99))}


def _time(fn: Callable[[], Any], n: int) -> dict[str, float]:
    for _ in range(WARM):
        fn()
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return _stats(out)


def _app(url: str) -> Any:
    from cmrt.settings import get_settings
    from service.app import create_app

    return create_app(get_settings().model_copy(update={"database_url": url}), run_drivers=False)


def in_process(url: str, n: int) -> dict[str, dict[str, float]]:
    from service.security import allowed_methods

    app = _app(url)
    repo = app.state.services.repo
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": "GET", "scheme": "http", "path": "/health", "raw_path": b"/health",
             "query_string": b"", "root_path": "", "headers": [(b"host", b"127.0.0.1")],
             "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 8000)}

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def call() -> None:
        status = []

        async def send(m: dict[str, Any]) -> None:
            if m["type"] == "http.response.start":
                status.append(m["status"])

        await app({**scope, "state": {}}, receive, send)
        if status != [200]:
            raise RuntimeError(f"/health answered {status}")

    async def run() -> dict[str, float]:
        for _ in range(WARM):
            await call()
        out = []
        for _ in range(n):
            t0 = time.perf_counter()
            await call()
            out.append(time.perf_counter() - t0)
        return _stats(out)

    rows = {"app in process (ASGI call)": asyncio.run(run()),
            "allowed_methods (every route x method)": _time(
                lambda: allowed_methods(app, scope), n),
            "list_jobs(limit=1) (the ping before)": _time(lambda: repo.list_jobs(limit=1), n)}
    if hasattr(repo, "ping"):
        rows["Repository.ping"] = _time(repo.ping, n)
    return rows


def over_loopback(url: str, n: int, http_impl: str, loop: str) -> dict[str, float]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # the product as this interpreter has it installed (another checkout's .venv/bin/python
    # measures that checkout)
    code = ("import sys, uvicorn; from bench.http_floor import _app; "
            "uvicorn.run(_app(sys.argv[1]), host='127.0.0.1', port=int(sys.argv[2]), "
            "http=sys.argv[3], loop=sys.argv[4], log_level='warning')")
    proc = subprocess.Popen([sys.executable, "-c", code, url, str(port), http_impl, loop],
                            stdout=subprocess.DEVNULL, cwd=tempfile.gettempdir())
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
                conn.request("GET", "/health")
                conn.getresponse().read()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

        def get() -> None:
            conn.request("GET", "/health")
            r = conn.getresponse()
            r.read()
            if r.status != 200:
                raise RuntimeError(f"/health answered {r.status}")

        return _time(get, n)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--requests", type=int, default=2000)
    ap.add_argument("--database", help="SQLAlchemy URL (default: a fresh SQLite file)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    url = args.database or f"sqlite:///{tempfile.mkdtemp(prefix='cmrt-floor-')}/cmrt.db"
    load0 = os.getloadavg()[0]
    rows = in_process(url, args.requests)
    for http_impl, loop in (("h11", "asyncio"), ("httptools", "uvloop")):
        if any(importlib.util.find_spec(m) is None for m in {http_impl, loop} - {"asyncio"}):
            continue  # not installed in this interpreter
        rows[f"uvicorn {http_impl} + {loop}, loopback"] = over_loopback(
            url, args.requests, http_impl, loop)
    load = [load0, os.getloadavg()[0]]
    if args.json:
        print(json.dumps({"load": load, "rows": rows}, indent=1))
        return 0
    print(f"GET /health, {args.requests} calls each; load average {load[0]:.1f} before, "
          f"{load[1]:.1f} after")
    print("| what | p50 ms | p99 ms |\n|---|---|---|")
    for k, v in rows.items():
        print(f"| {k} | {v['p50']:.3f} | {v['p99']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
