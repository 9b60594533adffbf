"""`/families` over HTTP: a family grows the library in one request (its runs are jobs), its
checks come back with it; bad input is a 422 naming the field and stores nothing; cancel."""

from __future__ import annotations

import time
from typing import Any

import pytest

BASE: dict[str, Any] = {
    "name": "fam", "family": "famtest", "task": {"type": "quiet_stance"},
    "clip": {"preparation": 0.5, "duration": 0.4, "decay": 1.0},
    "optimize": {"min_evaluations": 0, "window": 2, "improvement": 0.01, "popsize": 4,
                 "max_evaluations": 8},
}


def _family(**kw: Any) -> dict[str, Any]:
    return {"spec": BASE, "param": "clip.decay", "values": [1.0, 1.2, 1.4, 1.6, 1.8],
            "strategy": "continuation", "from": "both", "leave_out": [1.4],
            "warm": {"sigma0": 0.05, "window": 2, "max_evaluations": 4}, "k": 2, "seed": 2,
            **kw}


def _wait(client, url: str, timeout: float = 240.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        body = client.get(url).json()
        if body["status"] != "running":
            return body
        time.sleep(0.2)
    raise AssertionError(f"family still running after {timeout} s: {body['progress']}")


@pytest.mark.parametrize(("change", "field"), [
    ({"param": "task.type"}, "param"),
    ({"param": "task.nothing"}, "param"),
    ({"values": []}, "values"),
    ({"values": [1.0, 1.2, -3.0, 1.6, 1.8]}, "values[2]"),
    ({"leave_out": [1.5]}, "leave_out[0]"),
    ({"k": 9}, "k"),
    ({"spec": {**BASE, "clip": {"preparation": -1}}}, "spec"),
    ({"spec": {**BASE, "optimize": {**BASE["optimize"], "max_evaluations": 20000},
               "clip": {"preparation": 1.0, "duration": 0.4, "decay": 8.0}},
      "values": [8.0, 8.5, 9.0, 9.5, 10.0], "leave_out": []}, "values"),
])
def test_bad_family_is_a_422_naming_the_field_and_stores_nothing(http_client, change, field):
    r = http_client.post("/families", json=_family(**change))
    assert r.status_code == 422, r.text
    assert r.json()["detail"].split(": ")[0].endswith(field) or f"{field}: " in r.json()[
        "detail"], r.json()["detail"]
    assert http_client.get("/families").json()["total"] == 0
    assert http_client.get("/jobs").json()["total"] == 0


def test_a_family_runs_as_jobs_and_reports_its_checks(client):
    r = client.post("/families", json=_family())
    assert r.status_code == 202, r.text
    acc = r.json()
    assert r.headers["location"] == acc["url"] and acc["budget"]["sim_seconds"] > 0
    body = _wait(client, acc["url"])
    assert body["status"] == "done", body.get("error")
    assert body["progress"]["done"] == body["progress"]["runs"]
    assert [m["value"] for m in body["members"]] == [1.0, 1.2, 1.4, 1.6, 1.8]
    assert body["basis"] is not None and len(body["checks"]["rows"]) == 1
    row = body["checks"]["rows"][0]
    assert row["value"] == 1.4 and row["relative_error"] is not None
    assert body["paper_table2"] is None  # the paper has Table 2 for the domino's mass only
    jobs = {j["id"]: j for j in client.get("/jobs", params={"limit": 200}).json()["items"]}
    for run in body["runs"]:
        assert run["job_id"] in jobs and jobs[run["job_id"]]["status"] in ("converged",
                                                                           "stopped")
    warm = [run for run in body["runs"] if run["warm_from"]]
    assert warm and all(jobs[run["job_id"]]["start"]["from"] == run["warm_from"]
                        for run in warm)
    decays = {c["task_parameters"]["duration"] for c in client.get(
        "/cmrts", params={"family": "famtest", "limit": 200}).json()["items"]}
    assert decays == {0.4}  # every member landed in the library (the key is the duration)
    assert client.get("/cmrts", params={"family": "famtest"}).json()["total"] >= 5
    curves = client.get(acc["url"], params={"curves": "true"}).json()["runs"]
    assert all(len(run["curve"]) >= 1 for run in curves)
    listed = client.get("/families").json()
    assert listed["total"] == 1 and listed["items"][0]["status"] == "done"
    page = client.get(body["links"]["dashboard"])
    assert page.status_code == 200 and "family.js" in page.text


def test_cancel_a_family(client):
    acc = client.post("/families", json=_family(
        spec={**BASE, "optimize": {**BASE["optimize"], "max_evaluations": 400}})).json()
    r = client.post(f"/families/{acc['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"] in (True, False)
    assert _wait(client, acc["url"], timeout=60)["status"] == "cancelled"
    assert client.post("/families/nope/cancel").status_code == 404
    assert client.get("/families/nope").status_code == 404
