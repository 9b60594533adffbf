"""The JSON endpoints the dashboard pages read (besides the ones of test_api.py): a job's best
CMRT so far, evaluation counts after a generation, the list of PCA bases."""

from __future__ import annotations

import pytest
from svc_helpers import bend_spec, wait_job


def test_best_is_null_before_the_first_generation(http_client):
    # stored, not driven
    job_id = http_client.post("/jobs", json={"spec": bend_spec()}).json()["id"]
    best = http_client.get(f"/jobs/{job_id}/best")
    assert best.status_code == 200
    assert best.json() == {"job_id": job_id, "status": "queued", "iterations": 0,
                           "best_objective": None, "params": None, "knot_times": None,
                           "values": None, "vertical_values": None, "curve": None,
                           "cmrt_id": None}
    assert http_client.get("/jobs/nope/best").status_code == 404


def test_best_evaluations_after_and_bases(client):
    ids = [client.post("/jobs", json={"spec": bend_spec(f"bend_{i}", d)}).json()["id"]
           for i, d in enumerate((0.3, 0.4, 0.5))]
    jobs = [wait_job(client, i) for i in ids]
    job = jobs[0]
    assert job["links"]["best"] == f"/jobs/{ids[0]}/best"
    assert job["links"]["dashboard"] == f"/dashboard/jobs/{ids[0]}"

    best = client.get(f"/jobs/{ids[0]}/best").json()
    assert best["params"] == job["best_params"] and best["iterations"] == 3
    assert best["best_objective"] == job["best_objective"]
    assert len(best["knot_times"]) == len(best["values"]) == 4
    t = best["curve"]["t"]
    assert t[0] == 0.0 and t[-1] == pytest.approx(0.3 + 0.3 + 0.2)  # the clip's length
    assert len(best["curve"]["dx"]) == len(t) and best["cmrt_id"] == job["cmrt_id"]
    if client.get(f"/cmrts/{job['cmrt_id']}").json()["winner"] == "search":
        assert client.get(f"/cmrts/{job['cmrt_id']}").json()["curve"] == best["curve"]

    # One request draws the family: each item's curve is the one GET /cmrts/{id} gives.
    listed = client.get("/cmrts", params={"family": "bend", "curves": "true"}).json()["items"]
    assert sorted(r["id"] for r in listed) == sorted(j["cmrt_id"] for j in jobs)
    for r in listed:
        assert r["curve"] == client.get(f"/cmrts/{r['id']}").json()["curve"]
    assert all(r["curve"] is None
               for r in client.get("/cmrts", params={"family": "bend"}).json()["items"])

    every = client.get(f"/jobs/{ids[0]}/evaluations").json()["generations"]
    assert [g["generation"] for g in every] == [-1, 0, 1, 2]
    assert [g["population"] for g in every] == [2, 4, 4, 4]  # final pair, then popsize 4
    assert all(g["done"] == g["population"] and g["pending"] == g["failed"] == 0
               and g["attempts"] == g["population"] and g["repeated"] == 0 for g in every)
    later = client.get(f"/jobs/{ids[0]}/evaluations", params={"after": 1}).json()
    assert later["after"] == 1 and [g["generation"] for g in later["generations"]] == [-1, 2]
    assert client.get(f"/jobs/{ids[0]}/evaluations", params={"after": -2}).status_code == 422

    first = client.post("/bases", json={"family": "bend", "k": 2}).json()
    second = client.post("/bases", json={"family": "bend", "k": 1}).json()
    page = client.get("/bases", params={"family": "bend"}).json()
    assert page["total"] == 2 and [b["id"] for b in page["items"]] == [second["id"], first["id"]]
    assert sorted(page["items"][1]["members"]) == sorted(j["cmrt_id"] for j in jobs)
    assert len(page["items"][1]["variance_explained"]) >= 2
    assert client.get("/bases", params={"family": "nope"}).json()["total"] == 0
    assert client.get("/bases", params={"limit": 0}).status_code == 422
