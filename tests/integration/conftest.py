"""The running topology (see harness.py): started once per test session."""

from __future__ import annotations

import os
import signal
import tempfile
import time
from pathlib import Path

import httpx
import pytest
from harness import make_topology

#: Short timeouts so faults resolve in seconds (production defaults: docker-compose.yml).
OVERRIDES = {
    "CMRT_LEASE_SECONDS": "3",
    "CMRT_STALL_TIMEOUT": "6",
    "CMRT_VISIBILITY_TIMEOUT": "60",
    "CMRT_EVAL_TIME_LIMIT": "20",
    "CMRT_BROKER_DEADLINE": "45",
    "CMRT_MAX_ATTEMPTS": "3",
    "CMRT_SCAN_INTERVAL": "0.5",
    "CMRT_POLL_INTERVAL": "0.1",
    "CMRT_WORKER_CONCURRENCY": "1",
    "CMRT_LOG_LEVEL": "INFO",
}
#: Fault-injection hooks of the workers (worker/faults.py): candidate 1 of generation 0 of any
#: job whose spec is named "poison" kills its worker process on every attempt; candidate 0 of
#: generation 1 of the fault drills' jobs (named "it_fault_*") takes FAULT_WINDOW_S longer, so
#: a drill can strike while that generation is half done (its clips take ~50 ms each).
FAULT_WINDOW_S = 3.0
WORKER_FAULTS = {"CMRT_FAULT_CRASH_ON": "poison:0:1",
                 "CMRT_FAULT_DELAY_ON": f"it_fault_*:1:0:{FAULT_WINDOW_S:g}"}


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


@pytest.fixture(scope="session")
def topology():
    work = Path(tempfile.mkdtemp(prefix="cmrt-it-"))
    topo = None
    # SIGTERM (a CI step's timeout, `kill`) as an interrupt, so that the finally below removes
    # the processes, namespaces, containers, networks and volumes of the run
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        topo = make_topology(work, dict(OVERRIDES))
        topo.start_redis()
        topo.create_database()
        topo.warm_up()
        topo.start("worker", WORKER_FAULTS)
        topo.start("worker", WORKER_FAULTS)
        topo.start("api")
        topo.wait_workers_ready(2)
        yield topo
    except BaseException:
        if topo is not None:
            print(topo.logs())
        raise
    finally:
        if topo is not None:
            topo.stop_all()
            topo.drop_database()
        if os.environ.get("CMRT_IT_KEEP_LOGS") is None:
            import shutil

            shutil.rmtree(work, ignore_errors=True)
        signal.signal(signal.SIGTERM, previous)


@pytest.fixture
def api(topology):
    with httpx.Client(base_url=topology.url(""), timeout=10) as c:
        yield c


@pytest.fixture(autouse=True)
def _logs_on_failure(request):
    yield
    if "topology" not in request.fixturenames:  # e.g. the harness' own unit tests
        return
    rep = getattr(request.node, "rep_call", None)
    if rep is not None and rep.failed:
        print(request.getfixturevalue("topology").logs())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    if rep.when == "call":
        item.rep_call = rep


def bend(name: str, duration: float = 0.3, **optimize) -> dict:
    """A short bend clip (~0.8 s of simulation per candidate)."""
    opt = {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0, "sigma0": 0.15}
    opt.update(optimize)
    return {
        "name": name,
        "family": "it_bend",
        "clip": {"preparation": 0.3, "duration": duration, "decay": 0.2},
        "task": {"type": "pose_change",
                 "target": {"waist": -30, "shoulder_r": 30, "shoulder_l": 30}},
        "optimize": opt,
    }


def submit(api: httpx.Client, spec: dict, seed: int = 1) -> str:
    # From the flat spline: a job is then a function of its spec and seed alone (a library
    # start would depend on what earlier jobs left), which the fault drills compare against.
    r = api.post("/jobs", json={"spec": spec, "seed": seed, "start": "cold"})
    assert r.status_code == 202, r.text
    return r.json()["id"]


def wait_job(api: httpx.Client, job_id: str, timeout: float = 120, until=None) -> dict:
    """Poll until the job is finished (or `until(job)` holds); fail after `timeout` s."""
    t0 = time.monotonic()
    job: dict = {}
    while time.monotonic() - t0 < timeout:
        try:
            job = api.get(f"/jobs/{job_id}").json()
        except httpx.HTTPError:
            time.sleep(0.3)
            continue
        if (until(job) if until else job["status"] in
                ("converged", "stopped", "failed", "cancelled")):
            return job
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} not done after {timeout} s: {job}")


def bookkeeping(api: httpx.Client, job_id: str) -> dict:
    """Evaluations expected, stored once (done), lost, repeated attempts, failed."""
    gens = api.get(f"/jobs/{job_id}/evaluations").json()["generations"]
    pop = sum(g["population"] for g in gens)
    done = sum(g["done"] for g in gens)
    return {"expected": pop, "done": done, "lost": pop - done - sum(g["failed"] for g in gens),
            "failed": sum(g["failed"] for g in gens),
            "repeated": sum(g["repeated"] for g in gens), "per_generation": gens}


def result_of(api: httpx.Client, job_id: str) -> dict:
    """What a job computed: its best objective and parameters and every generation's
    statistics (not its timings): equal for two runs of one spec and seed whatever happened
    to the workers, the driver or the broker on the way."""
    job = api.get(f"/jobs/{job_id}").json()
    best = api.get(f"/jobs/{job_id}/best").json()
    gens = api.get(f"/jobs/{job_id}/generations").json()["generations"]
    return {"status": job["status"], "best_objective": job["best_objective"],
            "params": best["params"],
            "generations": [{k: v for k, v in g.items() if k not in ("wall_time", "created_at")}
                            for g in gens]}


def same_as_uninterrupted(api: httpx.Client, job_id: str, timeout: float = 180) -> bool:
    """Runs the job's spec again with its seed, nothing interrupting it, and says whether the
    two results are equal (`result_of`); prints the verdict."""
    job = api.get(f"/jobs/{job_id}").json()
    again = submit(api, job["spec"], seed=job["seed"])
    wait_job(api, again, timeout)
    a, b = result_of(api, job_id), result_of(api, again)
    same = a == b
    if not same:
        for key in ("status", "best_objective", "params"):
            if a[key] != b[key]:
                print(f"  {key}: {a[key]!r} vs {b[key]!r}")
        for ga, gb in zip(a["generations"], b["generations"], strict=False):
            if ga != gb:
                print(f"  generation {ga['iteration']}: {ga} vs {gb}")
    print(f"[{job['spec']['name']}] result equal to the uninterrupted run with seed "
          f"{job['seed']}: {same} (best {a['best_objective']!r} vs {b['best_objective']!r})")
    return same
