"""`python tests/service/fuzz_server.py DATA_DIR PORT [drivers]`: the API for the schemathesis
run.

On a fresh SQLite database in DATA_DIR it first fills the library the real way, through the
HTTP API (three bend jobs optimised against the synthetic objective, a PCA basis and a small
family, its runs against the synthetic objective and its probes simulated; with the bearer
token of CMRT_API_TOKEN when the environment sets one), prints the ids as one JSON line, then
serves the app under uvicorn on 127.0.0.1:PORT. By default the job drivers are off, so the jobs
(and families) the fuzzer submits are validated and stored but start no simulation; with
`drivers` they are on, as in production: every job the fuzzer gets accepted is optimised for
real (ODE in the local process pool, one worker) under a job ceiling of `DRIVEN_JOB_SIM_SECONDS`
simulated seconds, while the fuzzer goes on.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import uvicorn
from fastapi.testclient import TestClient

sys.path.insert(0, str(Path(__file__).parent))
sys.path += [str(Path(__file__).parents[2]), str(Path(__file__).parents[1])]  # for `synthetic`
from local_pool import local_executor  # noqa: E402
from svc_helpers import LOCAL, bend_spec  # noqa: E402
from synthetic import Sphere  # noqa: E402

from cmrt.settings import Settings  # noqa: E402
from optim.executors import SerialExecutor  # noqa: E402
from service.app import create_app  # noqa: E402
from service.schemas import JOB_EXAMPLE  # noqa: E402
from store import open_repository  # noqa: E402

TERMINAL = ("converged", "stopped", "failed", "cancelled")
#: A small family for /families/{family_id}: the quiet stance along its decay, 4 members by
#: continuation, one left out (its probe one short clip).
FAMILY = {"spec": {"name": "calm", "family": "calm", "task": {"type": "quiet_stance"},
                   "clip": {"preparation": 0.3, "duration": 0.2, "decay": 0.4},
                   "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0,
                                "window": 2}},
          "param": "clip.decay", "values": [0.4, 0.5, 0.6, 0.7], "strategy": "continuation",
          "leave_out": [0.5], "k": 2, "seed": 1,
          "warm": {"max_evaluations": 4, "window": 2}}


def _auth(settings: Settings) -> dict[str, str]:
    token = settings.api_token.get_secret_value() if settings.api_token else ""
    return {"Authorization": f"Bearer {token}"} if token else {}


def seed_library(settings: Settings) -> dict[str, str]:
    repo = open_repository(settings.database_url)
    config = settings.model_copy(update={"poll_interval": 0.02, "scan_interval": 0.1})
    executor = local_executor(config, SerialExecutor(), lambda spec: Sphere(centre=0.3))
    with TestClient(create_app(config, repo=repo, executor=executor),
                    headers=_auth(settings), base_url=LOCAL) as c:
        jobs = [c.post("/jobs", json={"spec": bend_spec(f"bend_{i}", d)}).json()["id"]
                for i, d in enumerate((0.3, 0.4, 0.5))]
        deadline = time.monotonic() + 60
        while any(c.get(f"/jobs/{j}").json()["status"] not in TERMINAL for j in jobs):
            if time.monotonic() > deadline:
                raise SystemExit("fuzz_server: the seed jobs did not finish in 60 s")
            time.sleep(0.05)
        basis = c.post("/bases", json={"family": "bend", "k": 2}).json()["id"]
        cmrt = c.get(f"/jobs/{jobs[0]}").json()["cmrt_id"]
        family = c.post("/families", json=FAMILY).json()["id"]
        deadline = time.monotonic() + 120
        while (status := c.get(f"/families/{family}").json()["status"]) == "running":
            if time.monotonic() > deadline:
                raise SystemExit("fuzz_server: the seed family did not finish in 120 s")
            time.sleep(0.05)
        if status != "done":
            raise SystemExit(f"fuzz_server: the seed family ended {status}")
    return {"job_id": jobs[0], "cmrt_id": cmrt, "basis_id": basis, "family_id": family}


#: The job ceiling (simulated s) with the drivers on: the example job (700 evaluations of a 2.6 s
#: clip) fits, a fuzzed job asking for 100,000 evaluations does not.
DRIVEN_JOB_SIM_SECONDS = 2500.0


def main(data_dir: str, port: int, drivers: bool = False) -> None:
    settings = Settings(data_dir=Path(data_dir), database_url=f"sqlite:///{data_dir}/fuzz.db",
                        workers=1)
    ids = seed_library(settings)
    if drivers:
        settings = settings.model_copy(update={"max_job_sim_seconds": DRIVEN_JOB_SIM_SECONDS})
    app = create_app(settings, run_drivers=drivers)
    # a job for the cancel operation: left queued (drivers off), or one that runs for minutes
    # (700 evaluations, no early-stopping threshold) when the drivers are on
    job = {**JOB_EXAMPLE, "optimize": {"max_evaluations": 700}}
    client = TestClient(app, headers=_auth(settings), base_url=LOCAL)
    ids["queued_job_id"] = client.post("/jobs", json={"spec": job}).json()["id"]
    # a family for the cancel operation: left running (drivers off; with them on it runs as
    # the seeded one did, its members simulated this time)
    ids["running_family_id"] = client.post("/families", json=FAMILY).json()["id"]
    print(json.dumps(ids), flush=True)
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), drivers=sys.argv[3:] == ["drivers"])
