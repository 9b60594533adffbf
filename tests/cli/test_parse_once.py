"""A job's spec changes form once: it is parsed and canonicalised where it enters (the command
line, the route) and every other process parses it at most once, found by its hash
(`sim.spec.CanonicalSpec`, `optim.objective.SPECS`). Counted with the spec trace
(`CMRT_SPEC_TRACE`: one line per parse and per serialisation, with the process id) on the three
paths: `cmrt optimize`, the embedded service, and the service with Celery workers."""

from __future__ import annotations

import os
import subprocess
import time
import uuid
from collections import Counter
from pathlib import Path

import httpx
import pytest
import yaml
from test_client import CMRT, _env, _serve, _stop, bend

from sim.spec import TRACE_VARIABLE

REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")


def _trace(path: Path, name: str) -> tuple[Counter, Counter]:
    """(parses, serialisations) of the spec `name`, per process id."""
    parses: Counter = Counter()
    serialised: Counter = Counter()
    for line in path.read_text().splitlines():
        pid, kind, spec, _source = line.split(" ", 3)
        if spec != name:
            continue
        (parses if kind == "parse" else serialised)[int(pid)] += 1
    return parses, serialised


def _run_job(url: str, name: str) -> str:
    job = httpx.post(f"{url}/jobs", json={"spec": bend(name, 0.3), "start": "cold"},
                     timeout=30).json()["id"]
    t0 = time.monotonic()
    while (status := httpx.get(f"{url}/jobs/{job}", timeout=30).json()["status"]) not in (
            "stopped", "converged", "failed"):
        assert time.monotonic() - t0 < 180, f"job {job} still {status}"
        time.sleep(0.2)
    assert status in ("stopped", "converged")
    for _ in range(3):  # a page polling the best candidate parses nothing more
        assert httpx.get(f"{url}/jobs/{job}/best", timeout=30).json()["curve"] is not None
    return job


def test_cmrt_optimize_parses_once_per_process(tmp_path: Path) -> None:
    spec = tmp_path / "once.yaml"
    spec.write_text(yaml.safe_dump(bend("once_cli", 0.3)))
    trace = tmp_path / "trace"
    proc = subprocess.Popen([str(CMRT), "optimize", str(spec), "--workers", "2", "--seed", "1",
                             "--out", str(tmp_path / "r.json")], cwd=tmp_path,
                            env=_env(**{TRACE_VARIABLE: str(trace)}),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err.decode()[-2000:]
    parses, serialised = _trace(trace, "once_cli")
    # the command line: one parse (the file) and one canonical form; each pool process: the
    # one parse of the text its first candidate carried, no serialisation
    assert parses[proc.pid] == 1 and serialised == Counter({proc.pid: 1})
    pool = set(parses) - {proc.pid}
    assert len(pool) == 2 and all(parses[p] == 1 for p in pool)


def test_embedded_service_parses_a_job_spec_once_per_process(tmp_path: Path) -> None:
    trace = tmp_path / "trace"
    api, url = _serve(tmp_path, CMRT_WORKERS="2", **{TRACE_VARIABLE: str(trace)})
    try:
        _run_job(url, "once_embedded")
    finally:
        _stop(api)
    parses, serialised = _trace(trace, "once_embedded")
    # the API process: the route's parse and canonical form; its driver and the best-candidate
    # reads find the spec by its hash
    assert parses[api.pid] == 1 and serialised == Counter({api.pid: 1})
    pool = set(parses) - {api.pid}
    assert 1 <= len(pool) <= 2 and all(parses[p] == 1 for p in pool)


def test_celery_path_parses_a_job_spec_once_per_process(tmp_path: Path) -> None:
    import redis

    broker = f"{REDIS}/{9 + uuid.uuid4().int % 6}"
    try:
        redis.Redis.from_url(broker, socket_timeout=2).ping()
    except Exception as err:  # noqa: BLE001
        pytest.skip(f"Redis at {broker} unreachable: {err}")
    trace = tmp_path / "trace"
    env = {"CMRT_BROKER_URL": broker, "CMRT_QUEUE": f"q{uuid.uuid4().hex[:8]}",
           "CMRT_DATABASE_URL": f"sqlite:///{tmp_path}/once.db", TRACE_VARIABLE: str(trace)}
    api, url = _serve(tmp_path, **env)
    worker = subprocess.Popen([str(CMRT), "worker", "--concurrency", "2", "--hostname",
                               f"once-{uuid.uuid4().hex[:6]}@%h"], cwd=tmp_path,
                              env=_env(CMRT_LOG_LEVEL="WARNING", **env),
                              stdout=(tmp_path / "worker.log").open("wb"),
                              stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _run_job(url, "once_celery")
    finally:
        _stop(worker)
        _stop(api)
    parses, serialised = _trace(trace, "once_celery")
    # the API process (route and driver): one parse, one canonical form; each Celery worker
    # process reads the stored document and hash: one parse, no serialisation
    assert parses[api.pid] == 1 and serialised == Counter({api.pid: 1})
    workers = set(parses) - {api.pid}
    assert 1 <= len(workers) <= 2 and all(parses[p] == 1 for p in workers)
