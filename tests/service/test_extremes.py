"""Every number of every example at the extremes an adversary sends, through `POST /jobs`:
each case answers a 422 naming the field, or is a job that ends normally (run for real, in the
local process pool, so a spec that makes ODE abort a process would show).

And the other side of the ranges: each prop's lightest mass (where ODE's `dMassCheck` aborted
the process for a few micrograms) is a job whose evaluations run in the real process pool and
end normally, no evaluation repeated after a dead process.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml
from fastapi.testclient import TestClient
from svc_helpers import LOCAL, TERMINAL

from service.app import create_app
from sim.spec import load_spec, numeric_fields
from worker.executors import LocalPoolExecutor

#: The example specs (examples/ also holds a user's character file, which is no spec).
EXAMPLES = sorted(p for p in (Path(__file__).parents[2] / "examples").glob("*.yaml")
                  if "segments" not in yaml.safe_load(p.read_text()))
#: The values of the adversarial round: subnormal, vanishing, huge (float and integer), and
#: the most negative double.
EXTREMES: tuple[float | int, ...] = (5e-324, -5e-324, 1e-30, 1e23, 10**23, 1e308, -1e308)
#: A job's budget in the runs below: the job machinery whole, a few evaluations.
TINY_BUDGET = {"popsize": 2, "max_evaluations": 2, "min_evaluations": 0}


def _with(data: dict[str, Any], path: tuple[str | int, ...], value: Any) -> dict[str, Any]:
    """A deep copy of `data` with `value` at `path` (a missing mapping key is added)."""
    out = copy.deepcopy(data)
    node: Any = out
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return out


def _cases() -> list[tuple[str, str, dict[str, Any]]]:
    cases = []
    for f in EXAMPLES:
        spec = load_spec(f)
        data = spec.model_dump(mode="json")
        for field in numeric_fields(spec):
            for v in EXTREMES:
                cases.append((f.stem, field.name, _with(data, field.path, v)))
    return cases


@pytest.fixture(scope="module")
def cases():
    return _cases()


def _real_app(config, repo):
    """The app with its drivers on and real evaluations (ODE) in a local process pool."""
    settings = config.model_copy(update={"workers": 2})
    executor = LocalPoolExecutor(settings)
    return create_app(settings, repo=repo, executor=executor), executor


def _run_jobs(config, repo, bodies: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Submit each spec as a job (budget `TINY_BUDGET`) and wait for them all to end."""
    import time

    app, executor = _real_app(config, repo)
    out = []
    with TestClient(app, base_url=LOCAL) as c:
        ids = []
        for body in bodies:
            body = {**body, "optimize": {**body.get("optimize", {}), **TINY_BUDGET}}
            r = c.post("/jobs", json={"spec": body})
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        deadline = time.monotonic() + 300
        for job_id in ids:
            while (job := c.get(f"/jobs/{job_id}").json())["status"] not in TERMINAL:
                assert time.monotonic() < deadline, job
                time.sleep(0.1)
            job["evaluation_summary"] = c.get(f"/jobs/{job_id}/evaluations").json()
            out.append(job)
    executor.close()
    return out


def test_every_number_of_every_example_at_the_extremes(http_client, config, repo, cases):
    fields = {(ex, name) for ex, name, _ in cases}
    accepted = []
    for example, name, body in cases:
        r = http_client.post("/jobs", json={"spec": body})
        if r.status_code == 202:
            accepted.append((example, name, body))
            continue
        assert r.status_code == 422, (example, name, r.status_code, r.text)
        detail = r.json()["detail"]
        assert detail.startswith(f"spec: {name}: "), (example, name, detail)
    print(f"\nextremes: {len(fields)} numeric fields of {len(EXAMPLES)} examples, "
          f"{len(cases)} cases, {len(cases) - len(accepted)} refused with the field named, "
          f"{len(accepted)} accepted")
    assert len(EXAMPLES) >= 17 and len(fields) >= 600
    if accepted:  # each must be a job that ends normally
        for job in _run_jobs(config, repo, [b for _, _, b in accepted]):
            assert job["status"] in ("converged", "stopped"), job


def test_the_messages_give_the_unit_and_the_range(http_client):
    spec = load_spec(next(f for f in EXAMPLES if f.stem == "domino")).model_dump(mode="json")
    for value, rule in ((1e-12, "must be from 1 to 1000 kg, got 1e-12"),
                        (5e-324, "must be from 1 to 1000 kg, got 5e-324"),
                        (10**23, "must be from 1 to 1000 kg, got an integer of 24 digits")):
        r = http_client.post("/jobs", json={"spec": _with(spec, ("task", "mass"), value)})
        assert r.status_code == 422 and r.json()["detail"] == f"spec: task.mass: {rule}"
    r = http_client.post("/jobs", json={"spec": _with(spec, ("task", "distance"), 1e-30)})
    assert r.json()["detail"] == ("spec: task.distance: must be 0 or at least 1e-09 in size "
                                  "(from 0 to 3 m), got 1e-30")
    assert http_client.get("/jobs").json()["total"] == 0
    doc = http_client.get("/openapi.json").json()["components"]["schemas"]
    mass = doc["DominoConfig"]["properties"]["mass"]
    assert (mass["minimum"], mass["maximum"]) == (1.0, 1000.0)
    assert "kg" in mass["description"]
    opt = doc["OptimizeConfig"]["properties"]
    for name in ("min_evaluations", "window"):
        assert opt[name]["maximum"] == 100_000, name
    assert opt["threshold"]["anyOf"][0]["maximum"] == 1e6


#: (example, path of a prop's mass): the lightest mass each prop may have.
LIGHTEST = [("domino", ("task", "mass")), ("catch", ("task", "ball", "mass")),
            ("sumo_pull", ("task", "mass")), ("sumo_pull", ("task", "chain", "mass")),
            ("punch", ("task", "mass")), ("lion_dodge", ("task", "tire", "mass"))]


def test_the_lightest_props_run_in_the_process_pool(config, repo):
    bodies = []
    for example, path in LIGHTEST:
        spec = load_spec(next(f for f in EXAMPLES if f.stem == example))
        field = next(x for x in numeric_fields(spec) if x.path == path)
        bodies.append(_with(spec.model_dump(mode="json"), path, field.lo))
    for (example, path), job in zip(LIGHTEST, _run_jobs(config, repo, bodies), strict=True):
        assert job["status"] in ("converged", "stopped"), (example, path, job)
        gens = job["evaluation_summary"]["generations"]
        assert gens and all(g["failed"] == 0 and g["repeated"] == 0
                            for g in gens), (example, path, gens)
