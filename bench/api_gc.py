"""The API process's garbage collections under library traffic, with and without freezing
what start-up built (`cmrt serve` freezes it: `service.command`).

    .venv/bin/python bench/api_gc.py [--requests 3000] [--db PATH]

Fills a SQLite library as `bench/library_scale.py` does (10,000 CMRTs in 200 families; `--db`
keeps and reuses the file), then, in one child process per variant (as served, start-up frozen
with `gc.freeze()`, and not frozen), makes the app (`service.app.create_app`, drivers off) and
asks `--requests` random interpolations and finds through an in-process client, timing every
collection with `gc.callbacks`: per generation the number of collections, their total and
longest pause (ms); then the objects the collector tracks and one full collection's time.
Pauses stop every request in flight, so the longest full collection is the API's worst added
latency. No assertions: the load average is printed; compare the variants within one run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import gc, json, os, random, sys, time
freeze, requests = sys.argv[1] == "frozen", int(sys.argv[2])
from service.app import create_app
from fastapi.testclient import TestClient
app = create_app()
if freeze:
    gc.collect()
    gc.freeze()
pauses = {0: [], 1: [], 2: []}
t0 = [0.0]
def timed(phase, info):
    if phase == "start":
        t0[0] = time.perf_counter()
    else:
        pauses[info["generation"]].append((time.perf_counter() - t0[0]) * 1000)
gc.callbacks.append(timed)
rng = random.Random(1)
with TestClient(app, base_url="http://localhost") as c:
    for _ in range(requests):
        fam, mass = f"domino_{rng.randrange(200):03d}", round(rng.uniform(30, 150), 2)
        for path, q in (("/cmrts/interpolate", {}), ("/cmrts", {"tolerance": 5})):
            assert c.get(path, params={"family": fam, "mass": mass, **q}).status_code == 200
gc.callbacks.remove(timed)
tracked = len(gc.get_objects())
t = time.perf_counter()
gc.collect()
full = (time.perf_counter() - t) * 1000
print(json.dumps({"pauses": pauses, "tracked": tracked, "full_ms": full}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--requests", type=int, default=3000)
    ap.add_argument("--db", type=Path, default=None)
    args = ap.parse_args()
    from bench.library_scale import _entries, _fill

    db = args.db or Path(tempfile.mkdtemp(prefix="cmrt-apigc-")) / "cmrt.db"
    if not db.exists():
        _fill(f"sqlite:///{db}", _entries(200, 50, 1))
    env = {"CMRT_DATABASE_URL": f"sqlite:///{db}", "CMRT_DATA_DIR": str(db.parent / "data"),
           "CMRT_API_DRIVERS": "false", "CMRT_LOG_LEVEL": "WARNING", "PATH": "/usr/bin:/bin",
           "PYTHONPATH": str(ROOT)}
    print(f"{args.requests} interpolations and {args.requests} finds, 10,000 CMRTs")
    print("| start-up | gen0 / gen1 / gen2 collections | gen2 total / longest ms | tracked "
          "objects after | one full collection ms |")
    print("|---|---|---|---|---|")
    for variant in ("frozen", "not frozen"):
        out = subprocess.run([sys.executable, "-c", CHILD, variant, str(args.requests)],
                             env=env, capture_output=True, text=True, check=True, cwd=ROOT)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        p = {int(k): v for k, v in r["pauses"].items()}
        print(f"| {variant} | {len(p[0])} / {len(p[1])} / {len(p[2])} | "
              f"{sum(p[2]):.0f} / {max(p[2], default=0):.0f} | {r['tracked']} | "
              f"{r['full_ms']:.0f} |")
    with open("/proc/loadavg") as f:
        print("load average", " ".join(f.read().split()[:3]))


if __name__ == "__main__":
    main()
