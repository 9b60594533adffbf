"""Helpers of the service unit tests."""

from __future__ import annotations

import time

#: The base URL of in-process test clients: a loopback name, as a local user's (Starlette's
#: default `testserver` is no name the API answers to, service.security).
LOCAL = "http://localhost"
TERMINAL = ("converged", "stopped", "failed", "cancelled")
#: A short real clip for what-if simulations and replays.
QUIET = {"name": "quiet", "family": "stand",
         "clip": {"preparation": 0.2, "duration": 0.3, "decay": 0.2},
         "task": {"type": "quiet_stance"}}


def wait_job(client, job_id: str, timeout: float = 30.0) -> dict:
    """The job's body once it is terminal (polling GET /jobs/{id})."""
    t0 = time.monotonic()
    j: dict = {}
    while time.monotonic() - t0 < timeout:
        j = client.get(f"/jobs/{job_id}").json()
        if j["status"] in TERMINAL:
            return j
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not finish: {j}")


def bend_spec(name: str = "bend_a", duration: float = 0.3, **optimize) -> dict:
    opt = {"popsize": 4, "max_evaluations": 12, "min_evaluations": 0}
    opt.update(optimize)
    return {
        "name": name,
        "family": "bend",
        "clip": {"preparation": 0.3, "duration": duration, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": opt,
    }
