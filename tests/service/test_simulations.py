"""POST /simulations: one real clip (ODE, the momentum controller) per request, in the API's
simulation pool; bad input is a 422 naming the field; a failing clip is a `failed` status and
the server stays up."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml
from fastapi.testclient import TestClient
from svc_helpers import LOCAL, QUIET, bend_spec, wait_job

from service.app import create_app

ROOT = Path(__file__).resolve().parents[2]


def test_clip_without_cmrt(client):
    r = client.post("/simulations", json={"spec": QUIET})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["status"] == "done" and out["fell"] is False and out["fall_direction"] is None
    assert out["cmrt"] is None and out["sim_seconds"] == pytest.approx(0.7)
    assert 0.0 <= out["objective"] < 0.05  # standing still: a few mm of CP error
    assert len(out["traces"]["t"]) == out["steps"] == 700
    assert out["frames"] is None


def test_cmrt_from_job_library_and_inline(client):
    job_id = client.post("/jobs", json={"spec": bend_spec("bend_x", 0.3)}).json()["id"]
    job = wait_job(client, job_id)
    spec = bend_spec("bend_x", 0.3)
    by_job = client.post("/simulations", json={"spec": spec, "traces": False,
                                               "cmrt": {"source": "job", "id": job_id}})
    assert by_job.status_code == 200, by_job.text
    a = by_job.json()
    assert a["status"] == "done" and a["cmrt"]["source"] == "job"
    assert a["cmrt"]["params"] == pytest.approx(job["best_params"])
    assert isinstance(a["fell"], bool) and a["traces"] is None and a["frames"] is None
    lib = client.post("/simulations", json={"spec": spec, "traces": False, "frames": True,
                                            "cmrt": {"source": "library",
                                                     "id": job["cmrt_id"]}}).json()
    assert lib["status"] == "done" and lib["cmrt"]["id"] == job["cmrt_id"]
    assert lib["frames"]["rate"] > 0 and len(lib["frames"]["poses"]) > 0
    inline = client.post("/simulations", json={
        "spec": spec, "traces": False,
        "cmrt": {"source": "params", "params": a["cmrt"]["params"]}}).json()
    assert inline["objective"] == a["objective"]  # same clip, same CMRT: bit for bit


def test_a_missed_punch_reports_the_cmrt_release(client):
    """The what-if of the punch mismatch: with a CMRT held, the miss (no hand on the bag by the
    end of the first strike, 1.2 s) releases it and the outcome says when; without a CMRT
    there is nothing to release."""
    miss = yaml.safe_load((ROOT / "examples/punch_miss.yaml").read_text())
    flat = client.post("/simulations", json={"spec": miss, "traces": False,
                                             "cmrt": {"source": "params", "params": [0.5] * 8}})
    assert flat.status_code == 200, flat.text
    assert flat.json()["cmrt_released_at"] == pytest.approx(1.2)
    none = client.post("/simulations", json={"spec": miss, "traces": False}).json()
    assert none["cmrt_released_at"] is None and none["objective"] == flat.json()["objective"]


@pytest.mark.parametrize(("body", "needle"), [
    ({"spec": {**QUIET, "clip": {"duration": -1}}}, "spec.clip.duration: "),
    ({"spec": QUIET, "cmrt": {"source": "params", "params": [0.5] * 3}},
     "cmrt.params: expected 8 numbers"),
    ({"spec": QUIET, "cmrt": {"source": "library", "id": "nope"}},
     "cmrt.id: no library CMRT 'nope'"),
    ({"spec": QUIET, "cmrt": {"source": "job", "id": "nope"}}, "cmrt.id: no job 'nope'"),
    ({"spec": QUIET, "cmrt": {"source": "crystal-ball"}}, "cmrt: "),
    ({"spec": QUIET, "replay": True}, "replay: Extra inputs are not permitted"),
    ({"spec": QUIET, "traces": "yes"}, "traces: "),
])
def test_bad_requests_name_the_field(client, body, needle):
    r = client.post("/simulations", json=body)
    assert r.status_code == 422, r.text
    assert needle in r.json()["detail"], r.json()["detail"]


def test_job_without_best_yet(http_client, repo):
    client = http_client  # drivers off: the job stays queued
    from sim.spec import parse_spec

    spec = parse_spec(bend_spec())
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=0)
    r = client.post("/simulations", json={"spec": QUIET, "cmrt": {"source": "job",
                                                                   "id": job.id}})
    assert r.status_code == 422
    assert r.json()["detail"] == f"cmrt.id: job {job.id!r} has no best candidate yet (queued)"


def test_time_limit_is_a_failed_status(settings, config, repo, local_executor):
    s = config.model_copy(update={"eval_time_limit": 0.05})
    with TestClient(create_app(s, repo=repo, executor=local_executor,
                               run_drivers=False), base_url=LOCAL) as c:
        long = {**QUIET, "clip": {"preparation": 1.0, "duration": 5.0, "decay": 1.0}}
        r = c.post("/simulations", json={"spec": long})
        out = r.json()
        assert r.status_code == 200 and out["status"] == "failed"
        assert out["error"] == "the clip ran past the time limit of 0.05 s"
        assert out["objective"] is None and out["traces"] is None
        assert c.get("/health").status_code == 200


def test_killed_process_is_a_failed_status_and_the_next_clip_runs(client):
    pool = client.app.state.services.simulations
    long = {**QUIET, "clip": {"preparation": 1.0, "duration": 8.0, "decay": 1.0}}
    result = {}
    t = threading.Thread(target=lambda: result.update(
        r=client.post("/simulations", json={"spec": long})))
    t.start()
    deadline = time.monotonic() + 20
    while not pool.pids() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    for pid in pool.pids():
        os.kill(pid, signal.SIGKILL)
    t.join(60)
    r = result["r"]
    assert r.status_code == 200 and r.json()["status"] == "failed"
    assert r.json()["error"].startswith("the simulation process died")
    again = client.post("/simulations", json={"spec": QUIET, "traces": False})
    assert again.status_code == 200 and again.json()["status"] == "done"


def test_a_task_window_shorter_than_a_step_is_refused(client):
    """Found by the schemathesis run: a pose change in 5e-324 s made the controller's numbers
    non-finite. The task window is now at least one 1 ms step: 422 naming the field and the
    rule, and the server carries on (a diverging ODE in a valid clip is still `failed`, see
    test_killed_process_is_a_failed_status_and_the_next_clip_runs and tests/sim/test_physics.py)."""
    spec = {**QUIET, "clip": {"preparation": 0.2, "duration": 5e-324, "decay": 0.2},
            "task": {"type": "pose_change", "target": {"waist": -90}}}
    r = client.post("/simulations", json={"spec": spec})
    assert r.status_code == 422, r.text
    assert "clip.duration: must be from 0.001 to 10 s, got 5e-324" in r.text, r.text
    assert client.post("/simulations", json={"spec": QUIET, "traces": False}).json()[
        "status"] == "done"


def test_pool_processes_end_with_a_killed_api(tmp_path):
    """A SIGKILLed API leaves no simulation process behind (they watch their parent)."""
    import subprocess
    import sys

    code = ("import asyncio, os, sys, time\n"
            "from application.simulations import SimulationPool\n"
            "pool = SimulationPool(1)\n"
            "spec = {'name': 'q', 'family': 's', 'task': {'type': 'quiet_stance'},\n"
            "        'clip': {'preparation': 0.2, 'duration': 0.3, 'decay': 0.2}}\n"
            "asyncio.run(pool.run(spec, None, traces=False, frames=False))\n"
            "print(*pool.pids(), flush=True)\n"
            "time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    children = [int(p) for p in proc.stdout.readline().split()]
    assert children
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10
    alive = children
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if os.path.exists(f"/proc/{p}")
                 and Path(f"/proc/{p}/stat").read_text().split()[2] != "Z"]
        time.sleep(0.1)
    assert not alive, f"simulation processes outlived their API: {alive}"
