"""What the library serves, checked: leave-one-out queries answered with `verify`, then refined
where the answer is not good, against a cold full-space optimisation at the same value.

    .venv/bin/python bench/library_answers.py FAMILY.json [FAMILY.json ...] [--cold COLD.json] \
        [--at 40 50 ...] [--between 45 ...] [--k 3] [--workers 2] [--json OUT.json]

The library holds every member of the given family reports (`application.library.
import_family`: what a service that ran those families holds). At each value of --at (default:
every interior member value) the members at that value are left out, and the product answers
as a user meets it, through the HTTP app in this process (the embedded default: SQLite, the
local process pool; nothing mocked): `GET /cmrts/interpolate?verify=true`, and, when the
verdict is not "good" or the answer is more than 5 % above the cold reference, a PCA basis of
the library (`POST /bases`, k = --k) and `POST /refinements` (the product's defaults: at most
150 evaluations in the basis, from the best answer), followed to its end. The final answer
is the better of the two that stand. The cold reference at a value is the member of the
`--cold` report there (a full-space run from the flat spline). Values of --between (no
reference) are answered the same way and reported without the comparison.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from application.library import import_family
from cmrt.settings import Settings
from sim.spec import parse_spec
from store import TERMINAL_STATUSES, open_repository

#: The target: a final answer within this fraction of the cold optimisation, or better.
WITHIN = 0.05


def _library(tmp: Path, reports: list[dict[str, Any]], key: str, leave: float | None) -> Any:
    repo = open_repository(f"sqlite:///{tmp}/library.db")
    for rep in reports:
        kept = [m for m in rep["members"] if leave is None or abs(m["value"] - leave) > 1e-9]
        import_family(repo, {**rep, "members": kept})
    return repo


def _answer(client: Any, family: str, key: str, value: float, cold: float | None, k: int,
            refine_always: bool) -> dict[str, Any]:
    t0 = time.perf_counter()
    a = client.get("/cmrts/interpolate", params={"family": family, key: value,
                                                 "verify": "true"}).json()
    if "outcome" not in a:
        raise SystemExit(f"{key} = {value}: {a}")
    row: dict[str, Any] = {
        "value": value, "source": a["source"], "switch": bool(a["switch"] and
                                                             a["switch"]["detected"]),
        "verdict": a["verdict"], "answer": a["outcome"]["objective"],
        "answer_fell": a["outcome"]["fell"], "answer_task": a["outcome"]["task_success"],
        "tried": len(a["tried"]), "predicted": a["predicted_objective"],
        "verify_seconds": time.perf_counter() - t0, "cold": cold,
        "interpolated": next((t["outcome"]["objective"] for t in a["tried"]
                              if t["source"] == "interpolated"), None),
    }
    final, final_src = a["outcome"]["objective"], a["source"]
    stands = a["verdict"] in ("good", "weak")
    need = (a["verdict"] != "good" or refine_always
            or (cold is not None and final > cold * (1 + WITHIN)))
    if need:
        if not client.get("/bases", params={"family": family}).json()["items"]:
            r = client.post("/bases", json={"family": family, "k": k})
            assert r.status_code == 201, r.text
        r = client.post("/refinements", json={"family": family, "parameters": {key: value}})
        assert r.status_code == 202, r.text
        job = r.json()
        t1 = time.perf_counter()
        while (got := client.get(job["url"]).json())["status"] not in TERMINAL_STATUSES:
            time.sleep(0.5)
        entry = client.get("/cmrts", params={"family": family, key: value}).json()["items"]
        refined = min(entry, key=lambda e: e["objective"]) if entry else None
        row.update(refine_status=got["status"], refine_evaluations=got["evaluations"],
                   refine_seconds=time.perf_counter() - t1,
                   refined=None if refined is None else refined["objective"],
                   refined_fell=None if refined is None else refined["fell"])
        # the refined member simulated once more, as any answer: its task success
        v = client.get("/cmrts/interpolate", params={"family": family, key: value,
                                                     "verify": "true"}).json()
        row["refined_task"] = v["outcome"]["task_success"] if v.get("outcome") else None
        if (refined is not None and not refined["fell"] and v["outcome"]["task_success"]
                is not False and (not stands or refined["objective"] < final)):
            final, final_src, stands = refined["objective"], "refined", True
    row.update(final=final, final_source=final_src, final_stands=stands)
    if cold is not None:
        row["vs_cold"] = final / cold - 1.0
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("reports", nargs="+", help="family reports (cmrt family run --out)")
    ap.add_argument("--cold", help="the report whose members are cold full-space runs")
    ap.add_argument("--at", type=float, nargs="*", help="leave-one-out values")
    ap.add_argument("--between", type=float, nargs="*", default=[])
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--refine-always", action="store_true")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    from fastapi.testclient import TestClient

    from service.app import create_app

    reports = [json.loads(Path(p).read_text()) for p in args.reports]
    base = parse_spec(reports[0]["spec"]["spec"])
    key = base.library_key(reports[0]["param"])
    family = base.family_name
    cold = {}
    if args.cold:
        cold = {m["value"]: m["objective"] for m in json.loads(Path(args.cold).read_text())
                ["members"]}
    values = sorted({m["value"] for m in reports[0]["members"]})
    at = args.at if args.at is not None else values[1:-1]
    rows = []
    for value, leave in [(v, v) for v in at] + [(v, None) for v in args.between]:
        with tempfile.TemporaryDirectory() as tmp:
            repo = _library(Path(tmp), reports, key, leave)
            settings = Settings(data_dir=Path(tmp), database_url=f"sqlite:///{tmp}/library.db",
                                workers=args.workers)
            with TestClient(create_app(settings, repo=repo), base_url="http://127.0.0.1") as client:
                row = _answer(client, family, key, value, cold.get(value) if leave else None,
                              args.k, args.refine_always)
            repo.engine.dispose()
        rows.append(row)
        print(json.dumps(row), flush=True)
    with_ref = [r for r in rows if r.get("cold") is not None]
    ok = [r for r in with_ref if r["final_stands"] and r["vs_cold"] <= WITHIN]
    evals = sorted(r["refine_evaluations"] for r in rows if "refine_evaluations" in r)
    print(f"stands and does its task: {sum(r['final_stands'] for r in rows)} of {len(rows)}; "
          f"within {WITHIN:.0%} of cold or better: {len(ok)} of {len(with_ref)}; refined "
          f"{len(evals)}, median evaluations "
          f"{evals[len(evals) // 2] if evals else '-'} (load {os.getloadavg()[0]:.1f})")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
