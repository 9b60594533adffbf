"""Screenshots of the dashboard's job page and library page (docs/img/), from real jobs.

    .venv/bin/python scripts/dashboard_screenshots.py [--out docs/img] [--evaluations 120]

Starts `cmrt serve` (embedded pool of 2 workers, SQLite in a temporary folder; the helper of
tests/browser/dashboard_server.py), optimises the CoP-objective fast bend of
examples/fast_bend_cop.yaml at task durations 0.4, 0.6 and 0.8 s (family `bend_cop`, seed 1,
`--evaluations` each, without the threshold so every run uses its budget), builds a PCA basis of
the three, and photographs `/dashboard/jobs/<the 0.4 s job>` and `/dashboard/library` in
Debian's Chromium (1280 px wide, full page). A few minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import httpx
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "browser"))
from dashboard_server import Server  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
DURATIONS = (0.4, 0.6, 0.8)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    ap.add_argument("--evaluations", type=int, default=120, help="max_evaluations per job")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    from playwright.sync_api import sync_playwright

    base = yaml.safe_load((ROOT / "examples" / "fast_bend_cop.yaml").read_text())
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        srv = Server(Path(tmp), workers=2)
        try:
            ids = []
            for d in DURATIONS:
                spec = {**base, "name": f"fast_bend_cop_{d}",
                        "clip": {**base["clip"], "duration": d},
                        "optimize": {"popsize": 8, "max_evaluations": args.evaluations,
                                     "min_evaluations": 0}}
                ids.append(srv.submit(spec, seed=args.seed))
            t0 = time.monotonic()
            srv.wait(ids, timeout=3600)
            print(f"jobs finished in {time.monotonic() - t0:.0f} s")
            r = httpx.post(srv.url + "/bases", json={"family": base["family"], "k": 2},
                           timeout=60)
            r.raise_for_status()
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                shots = {"dashboard-job.png": f"/dashboard/jobs/{ids[0]}",
                         "dashboard-library.png": f"/dashboard/library?family={base['family']}"}
                for name, path in shots.items():
                    page.goto(srv.url + path)
                    page.wait_for_selector("body[data-state]", timeout=60_000)
                    page.wait_for_timeout(500)  # the last plot's first frame and legends
                    page.screenshot(path=str(args.out / name), full_page=True)
                    print(f"wrote {args.out / name} ({srv.url}{path})")
                browser.close()
        finally:
            srv.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
