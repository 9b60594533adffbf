"""A real `cmrt serve` for the dashboard's browser tests (and scripts/dashboard_screenshots.py).

`serve(data_dir)` starts `.venv/bin/cmrt serve` on a free port, embedded default (SQLite in
`data_dir`, local pool of CMRT_WORKERS processes), in its own process group; `stop` ends the
group. `long_job(repo, generations)` writes a finished job of many generations straight
through the store repository: it is for the rendering test only (its figures are a smooth
made-up descent, not an optimisation; the real jobs of the tests come from the server).
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from proc_helpers import stop_group

ROOT = Path(__file__).resolve().parents[2]
CMRT = ROOT / ".venv" / "bin" / "cmrt"
TERMINAL = ("converged", "stopped", "failed", "cancelled")

#: A short bend: ~0.15 s of CPU per candidate (2.1 s clip), 4 candidates per generation.
SHORT_BEND: dict[str, Any] = {
    "name": "short_bend", "family": "bend",
    "clip": {"preparation": 0.5, "duration": 0.4, "decay": 1.2},
    "task": {"type": "pose_change", "target": {"waist": -90, "shoulder_r": 90, "shoulder_l": 90}},
    "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spec(name: str, *, family: str = "bend", duration: float = 0.4,
         max_evaluations: int = 4) -> dict[str, Any]:
    """SHORT_BEND with another name, family, task duration (s) and evaluation cap."""
    return {**SHORT_BEND, "name": name, "family": family,
            "clip": {**SHORT_BEND["clip"], "duration": duration},
            "optimize": {**SHORT_BEND["optimize"], "max_evaluations": max_evaluations}}


class Server:
    def __init__(self, data_dir: Path, workers: int = 2,
                 env_extra: dict[str, str] | None = None) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = data_dir / "serve.log"
        env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
        env.update(CMRT_DATA_DIR=str(data_dir), CMRT_WORKERS=str(workers),
                   CMRT_SCAN_INTERVAL="0.5", **(env_extra or {}))
        self.proc = subprocess.Popen([str(CMRT), "serve", "--port", str(self.port)], env=env,
                                     cwd=data_dir, stdout=self.log.open("wb"),
                                     stderr=subprocess.STDOUT, start_new_session=True)
        t0 = time.monotonic()
        while True:
            assert self.proc.poll() is None, self.log.read_text()[-3000:]
            try:
                if httpx.get(self.url + "/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() - t0 < 90, "cmrt serve did not become healthy"
            time.sleep(0.2)

    def submit(self, spec: dict[str, Any], **request: Any) -> str:
        """POST /jobs `{"spec": spec, **request}` (a seed, a basis, a start); the job's id."""
        r = httpx.post(self.url + "/jobs", json={"spec": spec, **request}, timeout=30)
        assert r.status_code == 202, r.text
        return r.json()["id"]

    def job(self, job_id: str) -> dict[str, Any]:
        return httpx.get(f"{self.url}/jobs/{job_id}", timeout=30).json()

    def wait(self, job_ids: list[str], timeout: float = 300.0) -> None:
        t0 = time.monotonic()
        for job_id in job_ids:
            while self.job(job_id)["status"] not in TERMINAL:
                assert time.monotonic() - t0 < timeout, f"job {job_id} did not finish"
                time.sleep(0.3)

    def stop(self) -> None:
        stop_group(self.proc)


def long_job(repo: Any, generations: int, *, name: str = "long_job", popsize: int = 8,
             seed: int = 3) -> str:
    """A stopped job of `generations` generations, each with `popsize` done evaluations (a few
    repeated, one failed), written through the repository (see the module docstring)."""
    from sim.spec import parse_spec

    s = parse_spec(spec("long_job", max_evaluations=generations * popsize))
    # the job's name as stored (the API would refuse one outside the spec's name pattern;
    # the store takes any text, which is what the escaping test needs)
    job = repo.create_job(s.model_dump(mode="json"), name=name, family=s.family_name,
                          task=s.task_type, seed=seed)
    repo.set_job_status(job.id, "running")
    rng = np.random.default_rng(seed)
    dim = s.cmrt_dimension
    best_so_far = math.inf
    for g in range(generations):
        scale = 0.9 + 8.0 * math.exp(-g / 25.0)
        objs = np.sort(scale * (1.0 + 0.3 * rng.random(popsize)))
        params = rng.random((popsize, dim)).tolist()
        repo.put_pending_evaluations(job.id, g, params)
        for i, o in enumerate(objs):
            failed = g == 7 and i == popsize - 1
            if g % 40 == 5 and i == 0:  # a repeated attempt: claimed twice, then done
                repo.claim_evaluation(job.id, g, i)
                repo.claim_evaluation(job.id, g, i)
            repo.store_result(job.id, g, i, objective=None if failed else float(o), fell=False,
                              cpu_seconds=0.1, error="synthetic failure" if failed else None)
        best_so_far = min(best_so_far, float(objs[0]))
        repo.record_generation(
            job.id, g, best=float(objs[0]), median=float(np.median(objs)),
            worst=float(objs[-1]), sigma=0.3 * math.exp(-g / 60.0), best_so_far=best_so_far,
            evaluations=(g + 1) * popsize, wall_time=0.5, candidates=params,
            optimizer_state=None, best_params=params[0])
    repo.set_job_status(job.id, "stopped", stop_rule="max_evaluations")
    return job.id
