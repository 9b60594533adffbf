"""A robust spec over HTTP: a bad robust block is a 422 naming the field, nothing stored; a
robust job run on the embedded service's local pool shows each variant's outcome and the range
at `GET /jobs/{id}`, as the command line's result has them."""

from __future__ import annotations

import pytest
from local_pool import local_executor

from optim.executors import SerialExecutor
from optim.run import optimize
from sim.spec import parse_canonical
from store.records import STOPPED
from worker.driver import JobDriver

SPEC = {"name": "robust_bend", "family": "robust_bend",
        "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0,
                     "robust": {"vary": {"task.target.waist": [-40, -20]}, "samples": 2,
                                "aggregate": "worst"}}}


@pytest.fixture
def client(http_client):
    return http_client


@pytest.mark.parametrize(("robust", "field"), [
    ({"vary": {"task.target.waist": [-20, -40]}}, "optimize.robust.vary.task.target.waist"),
    ({"vary": {"task.nope": [1, 2]}}, "optimize.robust.vary.task.nope"),
    ({"vary": {"task.target.waist": [-40, -20]}, "samples": 64}, "optimize.robust.samples"),
])
def test_a_bad_robust_block_is_a_422_naming_the_field(client, repo, robust, field):
    spec = {**SPEC, "optimize": {**SPEC["optimize"], "robust": robust}}
    r = client.post("/jobs", json={"spec": spec})
    assert r.status_code == 422 and field in r.json()["detail"], r.text
    assert repo.list_jobs()[1] == 0


def test_get_job_shows_the_variants_of_a_finished_robust_job(client, repo, config):
    r = client.post("/jobs", json={"spec": SPEC, "seed": 4})
    assert r.status_code in (201, 202), r.text
    job_id = r.json()["id"]
    assert client.get(f"/jobs/{job_id}").json()["robust"] is None  # not finished yet
    local = local_executor(config, SerialExecutor())  # the real objective
    try:
        assert JobDriver(repo, job_id, local, config).run() == STOPPED
    finally:
        local.close()
    got = client.get(f"/jobs/{job_id}").json()
    cli = optimize(parse_canonical(SPEC), SerialExecutor(), seed=4).to_dict()
    assert repr(got["robust"]) == repr(cli["robust"])
    assert got["robust"]["vary"] == {"task.target.waist": [-40.0, -20.0]}
    assert got["best_objective"] == max(v["objective"] for v in got["robust"]["variants"])
