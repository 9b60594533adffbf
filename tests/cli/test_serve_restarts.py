"""A rolling restart is not a crash: three SIGTERM / restart cycles of `cmrt serve`, each in
the middle of a generation, and the job ends with the uninterrupted run's result, every
evaluation counted once, the lease given back at each stop."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from local_pool import local_executor

from cmrt.settings import Settings
from optim.executors import SerialExecutor
from sim.spec import parse_spec
from store import open_repository
from worker.driver import JobDriver

ROOT = Path(__file__).resolve().parents[2]
CMRT = ROOT / ".venv" / "bin" / "cmrt"
#: ~0.15 s of CPU per candidate, 4 per generation, 3 generations + the final pair.
SPEC = {
    "name": "rolling", "family": "bend",
    "clip": {"preparation": 0.5, "duration": 0.4, "decay": 1.2},
    "task": {"type": "pose_change", "target": {"waist": -90, "shoulder_r": 90, "shoulder_l": 90}},
    "optimize": {"popsize": 4, "max_evaluations": 12, "min_evaluations": 0},
}
SEED = 5


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _uninterrupted(tmp_path: Path):
    settings = Settings(data_dir=tmp_path / "ref", database_url=f"sqlite:///{tmp_path}/ref.db",
                        workers=1)
    repo = open_repository(settings.database_url)
    spec = parse_spec(SPEC)
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type,
                          seed=SEED)
    ex = local_executor(settings, SerialExecutor())  # the real objective
    JobDriver(repo, job.id, ex, settings).run()
    return repo, job.id


def _start(env, port, log: Path) -> subprocess.Popen:
    return subprocess.Popen([str(CMRT), "serve", "--port", str(port)], env=env,
                            cwd=log.parent, stdout=log.open("ab"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def _wait_health(api: str, proc: subprocess.Popen) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        assert proc.poll() is None, f"cmrt serve exited {proc.returncode}"
        try:
            if httpx.get(f"{api}/health", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise AssertionError("cmrt serve did not become healthy")


def _running_candidates(db: Path, job_id: str) -> int:
    """Evaluations claimed and not finished (a candidate being evaluated right now)."""
    with sqlite3.connect(db) as c:
        return c.execute("SELECT count(*) FROM evaluations WHERE job_id = ? AND "
                         "status = 'pending' AND attempts > 0", (job_id,)).fetchone()[0]


def _iterations(db: Path, job_id: str) -> int:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT iterations FROM jobs WHERE id = ?", (job_id,)).fetchone()[0]


def _lease(db: Path, job_id: str):
    with sqlite3.connect(db) as c:
        return c.execute("SELECT driver_owner, status FROM jobs WHERE id = ?",
                         (job_id,)).fetchone()


@pytest.mark.slow
def test_three_sigterm_restarts_mid_generation_change_nothing(tmp_path):
    ref_repo, ref_id = _uninterrupted(tmp_path)
    ref = ref_repo.get_job(ref_id)
    assert ref.status == "stopped"

    db = tmp_path / "serve.db"
    port = _free_port()
    api = f"http://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(CMRT_DATABASE_URL=f"sqlite:///{db}", CMRT_WORKERS="1", CMRT_SCAN_INTERVAL="0.2",
               CMRT_LEASE_SECONDS="30")  # a lease not given back would stall the test 30 s
    log = tmp_path / "serve.log"
    proc = _start(env, port, log)
    try:
        _wait_health(api, proc)
        r = httpx.post(f"{api}/jobs", json={"spec": SPEC, "seed": SEED}, timeout=30)
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        stops = []
        for cycle in range(3):
            t0 = time.monotonic()  # a candidate of generation `cycle` (or later) running
            while _running_candidates(db, job_id) == 0 or _iterations(db, job_id) < cycle:
                assert time.monotonic() - t0 < 120, "no candidate ever ran"
                time.sleep(0.01)
            gen = _iterations(db, job_id)
            os.kill(proc.pid, signal.SIGTERM)  # what `docker stop` / systemd send
            assert proc.wait(30) == 0, log.read_text()[-3000:]
            owner, status = _lease(db, job_id)
            assert status == "running" and owner is None, "the lease was not given back"
            stops.append(gen)
            proc = _start(env, port, log)
            _wait_health(api, proc)
        t0 = time.monotonic()
        while (j := httpx.get(f"{api}/jobs/{job_id}", timeout=30).json())["status"] in (
                "queued", "running"):
            assert time.monotonic() - t0 < 300, j
            time.sleep(0.2)
        evs = httpx.get(f"{api}/jobs/{job_id}/evaluations", timeout=30).json()["generations"]
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGTERM)
            proc.wait(30)
    text = log.read_text()
    assert text.count("driver stops (shutdown)") == 3, text[-3000:]
    assert j["status"] == ref.status and j["error"] is None
    assert j["best_objective"] == ref.best_objective and j["best_params"] == ref.best_params
    assert j["evaluations"] == ref.evaluations and j["iterations"] == ref.iterations
    # nothing was repeated: the stopped attempts were given back, each candidate ran once
    assert all(g["repeated"] == 0 and g["failed"] == 0 for g in evs), evs
    got = sqlite3.connect(db).execute(
        "SELECT iteration, best FROM generations WHERE job_id = ? ORDER BY iteration",
        (job_id,)).fetchall()
    assert got == [(g.iteration, g.best) for g in ref_repo.generations(ref_id)]
    with sqlite3.connect(db) as c:
        entry = c.execute("SELECT objective, objective_without, winner FROM cmrts "
                          "WHERE job_id = ?", (job_id,)).fetchall()
    ref_entry = ref_repo.job_cmrt(ref_id)
    assert entry == [(ref_entry.objective, ref_entry.objective_without, ref_entry.winner)]
    print(f"SIGTERM at generations {stops}; {sum(g['attempts'] for g in evs)} attempts for "
          f"{sum(g['population'] for g in evs)} evaluations")
