"""The HTTP edge's probes against a live `cmrt serve` on PostgreSQL: a table of each probe's
status and message.

    .venv/bin/python bench/edge_probes.py [--pg postgresql+psycopg://postgres@127.0.0.1:5432/test]

Serves the API (`cmrt serve`, embedded executor, job drivers on) on a fresh PostgreSQL database
with an API token set (reads closed), then sends: physics-crashing specs (prop masses a few
orders below what ODE can run, subnormal and huge numbers) to `POST /jobs` and
`POST /simulations`; HEAD on GET routes and on a signed replay link; a state change from
another origin (same-site, another port); a signed link with a parameter added and one minted
for an unknown id; bidirectional controls in `family` and `name`; undecodable bytes in an id;
and, with the database refusing connections (`ALTER DATABASE ... ALLOW_CONNECTIONS false`, its
sessions terminated), the routes that read or write it. Prints a Markdown table; the database
is dropped at the end.
"""

from __future__ import annotations

import argparse
import copy
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import httpx
import yaml
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "probe-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SMALL = {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}


def _example(name: str, **task: Any) -> dict[str, Any]:
    spec = yaml.safe_load((ROOT / "examples" / f"{name}.yaml").read_text())
    spec = copy.deepcopy(spec)
    spec["optimize"] = {**spec.get("optimize", {}), **SMALL}
    for k, v in task.items():
        node = spec["task"]
        *head, last = k.split(".")
        for h in head:
            node = node.setdefault(h, {})
        node[last] = v
    return spec


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _row(rows: list[tuple[str, str, str]], probe: str, r: httpx.Response) -> None:
    body = (r.text if r.request.method != "HEAD"
            else f"(no body; Content-Length {r.headers.get('content-length')})")
    extra = f" [Retry-After: {r.headers['retry-after']}]" if "retry-after" in r.headers else ""
    rows.append((probe, str(r.status_code), body.replace("|", "\\|")[:160] + extra))
    print(f"{r.status_code}  {probe}: {body[:120]}{extra}", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pg", default="postgresql+psycopg://postgres@127.0.0.1:5432/test")
    args = ap.parse_args(argv)
    admin = create_engine(args.pg, isolation_level="AUTOCOMMIT")
    db = f"cmrt_probes_{uuid.uuid4().hex[:8]}"
    with admin.connect() as c:
        c.execute(text(f'CREATE DATABASE "{db}"'))
    url = make_url(args.pg).set(database=db).render_as_string(hide_password=False)
    port = _port()
    api = f"http://127.0.0.1:{port}"
    data = tempfile.mkdtemp(prefix="cmrt-probes-")
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("CMRT_")},
           "CMRT_DATABASE_URL": url, "CMRT_API_TOKEN": TOKEN, "CMRT_DATA_DIR": data,
           "CMRT_WORKERS": "1"}
    log = open(Path(data) / "server.log", "w")  # noqa: SIM115 - closed at the end
    server = subprocess.Popen([str(ROOT / ".venv" / "bin" / "cmrt"), "serve", "--host",
                               "127.0.0.1", "--port", str(port)], env=env, stdout=log,
                              stderr=subprocess.STDOUT, start_new_session=True)
    rows: list[tuple[str, str, str]] = []
    try:
        c = httpx.Client(base_url=api, timeout=120)
        for _ in range(300):
            try:
                if c.get("/health").status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        # 1. physics-crashing specs
        for probe, spec in (
                ("domino task.mass 1e-12", _example("domino", mass=1e-12)),
                ("sumo_pull task.mass 1e-30", _example("sumo_pull", mass=1e-30)),
                ("catch task.ball.mass 1e-12", _example("catch", **{"ball.mass": 1e-12})),
                ("sumo_pull task.chain.mass 1e-12",
                 _example("sumo_pull", **{"chain.mass": 1e-12})),
                ("domino task.mass 5e-324", _example("domino", mass=5e-324)),
                ("domino task.mass 1e308", _example("domino", mass=1e308)),
                ("domino task.distance 1e-30", _example("domino", distance=1e-30)),
                ("push task.force 10^23 (integer)", _example("push", force=10**23))):
            _row(rows, f"POST /jobs, {probe}", c.post("/jobs", json={"spec": spec}, headers=AUTH))
        opt = _example("domino")
        opt["optimize"] = {"min_evaluations": 10**9, "window": 10**9, "threshold": 1e308}
        _row(rows, "POST /jobs, optimize min_evaluations/window 10^9, threshold 1e308",
             c.post("/jobs", json={"spec": opt}, headers=AUTH))
        _row(rows, "POST /simulations, domino task.mass 1e-12",
             c.post("/simulations", json={"spec": _example("domino", mass=1e-12)},
                    headers=AUTH))
        # a real job for the rest
        job = c.post("/jobs", json={"spec": _example("fast_bend")}, headers=AUTH).json()["id"]
        # 3. HEAD
        _row(rows, "HEAD /health", c.head("/health"))
        _row(rows, "HEAD /jobs (token)", c.head("/jobs", headers=AUTH))
        _row(rows, f"HEAD /jobs/{job[:8]}... (token)", c.head(f"/jobs/{job}", headers=AUTH))
        link = c.post("/links", json={"path": f"/jobs/{job}/replay"}, headers=AUTH).json()
        _row(rows, "HEAD signed replay link (no token)", c.head(link["url"]))
        # 4. another origin
        _row(rows, "POST /jobs/{id}/cancel, Sec-Fetch-Site: same-site, Origin "
                   "http://127.0.0.1:9999, text/plain body",
             c.post(f"/jobs/{job}/cancel", content=b"x", headers={
                 **AUTH, "Sec-Fetch-Site": "same-site", "Origin": "http://127.0.0.1:9999",
                 "content-type": "text/plain"}))
        _row(rows, "POST /jobs/{id}/cancel, Origin http://127.0.0.1:9999 only",
             c.post(f"/jobs/{job}/cancel", headers={**AUTH, "Origin": "http://127.0.0.1:9999"}))
        # 5. signed links
        _row(rows, "GET signed link + &compare=false (no token)",
             c.get(link["url"] + "&compare=false"))
        _row(rows, "POST /links for an unknown job id",
             c.post("/links", json={"path": "/jobs/nosuchjob/replay"}, headers=AUTH))
        # 6. display spoofing, undecodable bytes
        _row(rows, "POST /jobs, family 'bend\\u202e'",
             c.post("/jobs", json={"spec": {**_example("fast_bend"), "family": "bend\u202e"}},
                    headers=AUTH))
        _row(rows, "POST /jobs, name 'a\\u202eb'",
             c.post("/jobs", json={"spec": {**_example("fast_bend"), "name": "a\u202eb"}},
                    headers=AUTH))
        _row(rows, "GET /jobs/%FF%FE", c.get("/jobs/%FF%FE", headers=AUTH))
        # 7. the /links path pattern
        doc = c.get("/openapi.json").json()
        pattern = doc["components"]["schemas"]["LinkRequest"]["properties"]["path"]["pattern"]
        rows.append(("API document: LinkRequest.path pattern", "-", pattern))
        print("pattern", pattern)
        # 2. database outage
        with admin.connect() as a:
            a.execute(text(f'ALTER DATABASE "{db}" ALLOW_CONNECTIONS false'))
            a.execute(text("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                           "WHERE datname = :d"), {"d": db})
        for method, path, body in (("GET", "/jobs", None), ("GET", f"/jobs/{job}", None),
                                   ("GET", "/cmrts", None),
                                   ("POST", "/jobs", _example("fast_bend")),
                                   ("POST", f"/jobs/{job}/cancel", None),
                                   ("HEAD", "/jobs", None), ("GET", "/health", None)):
            _row(rows, f"outage: {method} {path.replace(job, '{id}')}",
                 c.request(method, path, json=body, headers=AUTH))
        with admin.connect() as a:
            a.execute(text(f'ALTER DATABASE "{db}" ALLOW_CONNECTIONS true'))
        time.sleep(1)
        after = c.get("/jobs", headers=AUTH).json()
        rows.append(("after the outage: GET /jobs total (1 job posted before)", "200",
                     str(after["total"])))
        print("after the outage", after["total"])
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
        log.close()
        with admin.connect() as a:
            a.execute(text(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)'))
        admin.dispose()
    print("\n| probe | status | message |\n|---|---|---|")
    for probe, status, msg in rows:
        print(f"| {probe} | {status} | `{msg}` |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
