"""`cmrt driver`: jobs and families driven by a process of their own, so that the API
(`CMRT_API_DRIVERS=false`) can be killed and restarted without stopping a job."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
from test_client import CMRT, _env, _serve, _stop, bend

LONGER = {"popsize": 4, "max_evaluations": 40, "min_evaluations": 0}


def _wait(url: str, job: str, statuses: tuple[str, ...], timeout: float = 180.0) -> dict:
    t0 = time.monotonic()
    while True:
        j = httpx.get(f"{url}/jobs/{job}", timeout=30).json()
        if j["status"] in statuses:
            return j
        assert time.monotonic() - t0 < timeout, f"job {job} still {j['status']}"
        time.sleep(0.2)


def test_jobs_go_on_while_the_api_is_killed_and_restarted(tmp_path: Path):
    env = {"CMRT_API_DRIVERS": "false", "CMRT_SCAN_INTERVAL": "0.3", "CMRT_LEASE_SECONDS": "5"}
    api, url = _serve(tmp_path, **env)
    driver = None
    try:
        first = httpx.post(f"{url}/jobs", json={"spec": bend("first", 0.3)},
                           timeout=30).json()["id"]
        time.sleep(2.0)
        assert httpx.get(f"{url}/jobs/{first}", timeout=30).json()["status"] == "queued"
        driver = subprocess.Popen(
            [str(CMRT), "driver", "--workers", "1"], cwd=tmp_path,
            env=_env(CMRT_DATA_DIR=str(tmp_path / "data"), CMRT_LOG_LEVEL="INFO", **env),
            stdout=(tmp_path / "driver.log").open("wb"), stderr=subprocess.STDOUT,
            start_new_session=True)
        assert _wait(url, first, ("stopped", "converged"))["cmrt_id"]
        spec = {**bend("second", 0.4), "optimize": LONGER}
        second = httpx.post(f"{url}/jobs", json={"spec": spec, "start": "cold"},
                            timeout=30).json()["id"]
        t0 = time.monotonic()
        while httpx.get(f"{url}/jobs/{second}", timeout=30).json()["iterations"] < 2:
            assert time.monotonic() - t0 < 120, "the second job made no generation"
            time.sleep(0.2)
        os.killpg(api.pid, signal.SIGKILL)  # the API dies mid-job; the driver goes on
        api.wait(10)
        time.sleep(1.0)
        api, url = _serve(tmp_path, **env)  # a new API process (on a new port)
        done = _wait(url, second, ("stopped", "converged", "failed"))
        assert done["status"] == "stopped" and done["evaluations"] == 40, done
        assert driver.poll() is None  # the same driver process drove it to its end
        gens = httpx.get(f"{url}/jobs/{second}/generations", timeout=30).json()["generations"]
        assert [g["iteration"] for g in gens] == list(range(10))
        log = (tmp_path / "driver.log").read_text()
        assert "driving jobs and families" in log
    finally:
        _stop(api)
        if driver is not None:
            driver.send_signal(signal.SIGTERM)
            assert driver.wait(30) == 0, (tmp_path / "driver.log").read_text()[-2000:]
