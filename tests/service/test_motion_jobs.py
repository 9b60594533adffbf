"""A motion (`task: {type: motion, ...}`) through `POST /jobs`: run for real in the local
process pool, its best objective the one the simulator gives for the same parameters (by
`repr`), its CMRT in the library under the motion's speed and scale; a bad motion is a 422
naming the field, and nothing is stored."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient
from svc_helpers import LOCAL, TERMINAL

from optim.objective import evaluate_params
from service.app import create_app
from sim.spec import parse_spec
from worker.executors import LocalPoolExecutor

MOTION = {"type": "motion", "rate": 10, "joints": ["waist", "shoulder_r", "shoulder_l"],
          "frames": [[0, 0, 0], [-10, 10, 10], [-35, 40, 40], [-50, 60, 60], [-50, 60, 60],
                     [-30, 35, 35], [-5, 5, 5], [0, 0, 0]]}
SPEC = {"name": "reach", "family": "reach",
        "clip": {"preparation": 0.4, "duration": 0.7, "decay": 0.4},
        "task": MOTION, "optimize": {"popsize": 2, "max_evaluations": 4, "min_evaluations": 0}}


def test_a_motion_job_runs_and_its_cmrt_joins_the_library(config, repo):
    settings = config.model_copy(update={"workers": 2})
    executor = LocalPoolExecutor(settings)
    try:
        with TestClient(create_app(settings, repo=repo, executor=executor),
                        base_url=LOCAL) as c:
            bad = {**SPEC, "task": {**MOTION, "joints": ["waist", "wrist", "neck"]}}
            r = c.post("/jobs", json={"spec": bad})
            assert r.status_code == 422, r.text
            assert r.json()["detail"].startswith("spec: task.joints.1: unknown joint 'wrist'")
            r = c.post("/jobs", json={"spec": {**SPEC, "task": {"type": "motion",
                                                                "file": "m.yaml"}}})
            assert r.status_code == 422 and "read by the command line" in r.json()["detail"]
            assert c.get("/jobs").json()["total"] == 0
            r = c.post("/jobs", json={"spec": SPEC, "seed": 3})
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
            deadline = time.monotonic() + 120
            while (job := c.get(f"/jobs/{job_id}").json())["status"] not in TERMINAL:
                assert time.monotonic() < deadline, job
                time.sleep(0.1)
            cmrt = c.get(f"/cmrts/{job['cmrt_id']}").json()
    finally:
        executor.close()
    assert job["status"] in ("converged", "stopped") and job["task"] == "motion", job
    assert job["evaluations"] >= 4
    own = evaluate_params(parse_spec(SPEC), job["best_params"])
    assert repr(own.objective) == repr(job["best_objective"])
    assert cmrt["task_parameters"] == {"duration": 0.7, "speed": 1.0, "scale": 1.0}
