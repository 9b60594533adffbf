"""HTTP API over a SQLite store with the embedded local executor (synthetic objective)."""

from __future__ import annotations

import json
import time

import pytest
from svc_helpers import bend_spec, wait_job


def _request(spec, **fields) -> bytes:
    """The body of a job request for `spec` (with `fields` beside it)."""
    return json.dumps({"spec": spec, **fields}).encode()


def _submit(client, spec, **kw):
    r = client.post("/jobs", json={"spec": spec, **kw})
    assert r.status_code == 202, r.text
    assert r.headers["location"].endswith(f"/jobs/{r.json()['id']}")
    return r.json()["id"]


def test_job_lifecycle_library_and_interpolation(client):
    a = _submit(client, bend_spec("bend_a", 0.3), seed=1)
    b = _submit(client, bend_spec("bend_b", 0.5))
    ja, jb = wait_job(client, a), wait_job(client, b)
    assert ja["status"] == "stopped" and ja["stop_rule"] == "max_evaluations"
    assert ja["cmrt_id"] and jb["cmrt_id"] and ja["seed"] == 1
    # every candidate was evaluated with this process's numerics: one fingerprint, the API's
    health = client.get("/health").json()
    assert ja["fingerprints"] == jb["fingerprints"] == [health["fingerprints"]["api"]]
    assert not health["mixed"] and len(health["fingerprints"]["api"]) == 16
    assert client.get("/jobs").json()["items"][0].get("fingerprints") is None  # by id only

    gens = client.get(f"/jobs/{a}/generations").json()
    assert [g["iteration"] for g in gens["generations"]] == [0, 1, 2]
    later = client.get(f"/jobs/{a}/generations?after=1").json()
    assert [g["iteration"] for g in later["generations"]] == [2] and later["last"] == 2
    ev = client.get(f"/jobs/{a}/evaluations").json()["generations"]
    assert all(g["done"] == g["population"] and g["repeated"] == 0 for g in ev)

    found = client.get("/cmrts", params={"family": "bend", "duration": 0.3}).json()
    assert found["total"] == 1 and found["items"][0]["id"] == ja["cmrt_id"]
    near = client.get("/cmrts", params={"family": "bend", "duration": 0.45,
                                        "tolerance": 0.1}).json()
    assert [c["id"] for c in near["items"]] == [jb["cmrt_id"]]
    assert client.get("/cmrts", params={"family": "bend", "duration": 0.45}).json()["total"] == 0
    fams = client.get("/cmrts/families").json()
    assert fams == {"items": [{"family": "bend", "count": 2}], "total": 1}
    one = client.get(f"/cmrts/{ja['cmrt_id']}").json()
    assert one["task_parameters"] == {"duration": 0.3} and one["source"]["job_id"] == a
    assert len(one["curve"]["t"]) == len(one["curve"]["dx"]) > 10

    mid = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.4})
    assert mid.status_code == 200, mid.text
    m = mid.json()
    assert {n["id"] for n in m["neighbours"]} == {ja["cmrt_id"], jb["cmrt_id"]}
    assert m["weight"] == pytest.approx(0.5) and not m["extrapolated"]
    out = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.7})
    assert out.status_code == 422 and "extrapolate" in out.json()["detail"]
    ext = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.6,
                                                   "extrapolate": "true"})
    assert ext.status_code == 200 and ext.json()["extrapolated"]

    listed = client.get("/jobs", params={"status": "stopped", "family": "bend", "limit": 1})
    assert listed.json()["total"] == 2 and len(listed.json()["items"]) == 1
    assert client.get("/jobs", params={"status": "bogus"}).status_code == 422


def test_basis_and_reduced_space_job(client):
    ids = [_submit(client, bend_spec(f"bend_{i}", d)) for i, d in enumerate((0.3, 0.4, 0.5))]
    for i in ids:
        wait_job(client, i)
    r = client.post("/bases", json={"family": "bend", "k": 2})
    assert r.status_code == 201, r.text
    basis = r.json()
    assert basis["k"] == 2 and len(basis["members"]) == 3
    assert client.get(f"/bases/{basis['id']}").json()["id"] == basis["id"]
    j = _submit(client, bend_spec("bend_pca", 0.35), basis=basis["id"])
    job = wait_job(client, j)
    assert job["status"] == "stopped" and job["basis_id"] == basis["id"]
    assert len(job["best_params"]) == 8  # full spline params, searched in 2 dimensions
    nope = client.post("/bases", json={"family": "nope", "k": 2})
    assert nope.status_code == 404
    assert nope.json()["detail"] == "family: no library CMRTs of family 'nope'"
    assert client.post("/bases", json={"family": "bend", "k": 0}).status_code == 422
    bad = client.post("/jobs", json={"spec": bend_spec(), "basis": "missing"})
    assert bad.status_code == 422 and "basis" in bad.json()["detail"]


def test_cancel(client):
    j = _submit(client, bend_spec(max_evaluations=50000, min_evaluations=50000))
    time.sleep(0.3)
    r = client.post(f"/jobs/{j}/cancel")
    assert r.status_code == 202
    assert wait_job(client, j)["status"] == "cancelled"
    assert client.post(f"/jobs/{j}/cancel").status_code == 409
    assert client.get("/cmrts", params={"family": "bend"}).json()["total"] == 0
    assert client.post("/jobs/nope/cancel").status_code == 404


@pytest.mark.parametrize(
    ("body", "status", "needle"),
    [
        (b"{not json", 400, "malformed JSON"),
        (b"", 400, "empty"),
        (b'{"spec": {"name": "x", "task": {"type": "quiet_stance"}, '
         b'"clip": {"duration": NaN}}}', 400, "NaN"),
        (_request({**bend_spec(), "task": {"type": "juggle"}}), 422, "task"),
        (_request({**bend_spec(), "clip": {"duration": -1}}), 422, "clip.duration"),
        (_request({**bend_spec(), "typo": 1}), 422, "typo"),
        (_request({**bend_spec(), "task": "pose_change"}), 422,
         "task: must be a mapping with its type, e.g. {type: pose_change, ...}"),
        (_request({**bend_spec(), "controller": {"k_l": 30}}), 422,
         "controller.type: required: send {type: momentum, ...}"),
        (_request({**bend_spec(), "task": {"type": "sequence", "motions": [
            {"target": {"waist": 1}, "start": 0.0, "duration": 0.1}] * 40}}),
         422, "motions"),
        (_request(bend_spec(), seed=-1), 422, "seed: must be an integer in [0, 2^31)"),
        (_request(bend_spec(), seed=True), 422, "seed: must be an integer in [0, 2^31)"),
        (_request(bend_spec(), basis=7), 422, "basis: must be a basis id (string)"),
        (_request(bend_spec(), colour=1), 422,
         "colour: unknown field (allowed: spec, seed, basis, start)"),
        (b"[1, 2]", 422, "mapping"),
        (json.dumps(bend_spec()).encode(), 422, "spec: required; a job request is "
         '{"spec": ...} (a bare task spec as the whole body is no longer accepted: send it as '
         "`spec`)"),
        (b"{}", 422, "spec: required"),
        (b'{"name": "' + b"x" * 2_000_000 + b'"}', 413, "limit"),
    ],
)
def test_bad_input_is_rejected_and_nothing_stored(client, body, status, needle):
    r = client.post("/jobs", content=body, headers={"content-type": "application/json"})
    assert r.status_code == status, r.text
    assert needle in r.json()["detail"]
    assert client.get("/jobs").json()["total"] == 0


def test_the_earlier_request_forms_are_refused_saying_what_to_send(client):
    """One request form: a bare task spec as the whole body, and a seed, basis or start in
    the query (the body's fields repeated), are 422s that say where the field goes."""
    r = client.post("/jobs", json=bend_spec())
    assert r.status_code == 422
    assert r.json()["detail"] == ('spec: required; a job request is {"spec": ...} (a bare task '
                                  "spec as the whole body is no longer accepted: send it as "
                                  "`spec`)")
    for name, value in (("seed", 3), ("basis", "b"), ("start", "cold")):
        r = client.post("/jobs", params={name: value}, json={"spec": bend_spec()})
        assert r.status_code == 422
        assert r.json()["detail"] == (f"{name}: query parameters are not accepted; send it "
                                      "in the body")
    assert client.get("/jobs").json()["total"] == 0


def test_bad_queries(client):
    assert client.get("/jobs/nope").status_code == 404
    assert client.get("/cmrts/nope").status_code == 404
    assert client.get("/bases/nope").status_code == 404
    assert client.get("/cmrts", params={"family": "bend", "duration": "abc"}).status_code == 422
    assert client.get("/cmrts", params={"duration": 0.3}).status_code == 422
    r = client.get("/cmrts/interpolate", params={"family": "bend", "duration": "inf"})
    assert r.status_code == 422 and "finite" in r.json()["detail"]
    assert client.get("/cmrts/interpolate", params={"family": "bend"}).status_code == 422
    assert client.get("/jobs/x/generations", params={"after": -5}).status_code == 422


def test_health_openapi_dashboard(client):
    h = client.get("/health")
    assert h.status_code == 200 and h.json()["database"] == "ok"
    paths = client.get("/openapi.json").json()["paths"]
    for p in ("/jobs", "/jobs/{job_id}", "/jobs/{job_id}/generations", "/jobs/{job_id}/cancel",
              "/cmrts", "/cmrts/{cmrt_id}", "/cmrts/interpolate", "/cmrts/families", "/bases",
              "/bases/{basis_id}", "/health"):
        assert p in paths
    pages = {"/dashboard": "jobs.js", "/dashboard/jobs/x": "job.js",
             "/dashboard/library": "library.js"}
    for path, script_name in pages.items():
        page = client.get(path)
        assert page.status_code == 200, path
        assert f'<script src="/static/dash/{script_name}">' in page.text, path
    script = client.get("/static/dash/job.js")
    assert script.status_code == 200 and "/generations?after=" in script.text
    texts = [client.get(p).text for p in pages]
    texts += [client.get(f"/static/dash/{n}").text
              for n in ("common.js", "jobs.js", "job.js", "library.js", "dash.css")]
    for text in texts:  # no CDN, nothing fetched from elsewhere
        assert "http://" not in text and "https://" not in text
        assert "innerHTML" not in text  # user text goes through textContent only


def test_budget_is_shown_and_a_job_above_the_ceiling_is_refused(client, repo):
    r = client.post("/jobs", json={"spec": bend_spec("small", 0.3)})
    assert r.status_code == 202
    b = r.json()["budget"]
    assert b["evaluations"] == 12 + 3 + 2 and b["clip_seconds"] == pytest.approx(0.8)
    assert b["sim_seconds"] == pytest.approx(17 * 0.8) and b["ceiling_sim_seconds"] == 50_000
    huge = bend_spec("huge", 0.3, popsize=60, max_evaluations=100_000)
    huge["clip"] = {"preparation": 1.0, "duration": 10.0, "decay": 9.0}
    _, before = repo.list_jobs()
    r = client.post("/jobs", json={"spec": huge})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("optimize.max_evaluations: the job may simulate up to "
                                         "2,001,220 s")
    assert repo.list_jobs()[1] == before  # nothing stored


def test_a_job_near_library_members_starts_warm_unless_cold(client):
    """The library pays back: a job between two library CMRTs starts from their interpolation
    (with a small step), one at a stored value from that CMRT; `start: cold` from the flat
    spline; every job says where it started."""
    for name, t in (("lib_a", 0.3), ("lib_b", 0.5)):
        wait_job(client, _submit(client, bend_spec(name, t), start="cold"))
    warm = wait_job(client, _submit(client, bend_spec("mid", 0.4)))
    assert warm["start"]["from"].startswith("library: interpolated along duration between "
                                            "0.3 and 0.5 (weight 0.500)"), warm["start"]
    assert warm["start"]["sigma0"] == 0.05 and len(warm["start"]["x0"]) == 8
    assert len(warm["start"]["cmrts"]) == 2
    exact = wait_job(client, _submit(client, bend_spec("again", 0.3)))
    assert exact["start"]["from"].startswith("library CMRT ")
    cold = wait_job(client, _submit(client, bend_spec("cold", 0.4), start="cold"))
    assert cold["start"] is None
    outside = wait_job(client, _submit(client, bend_spec("far", 0.7)))
    assert outside["start"] is None  # no neighbours on both sides: the flat spline
    other_clip = {**bend_spec("longer", 0.4), "clip": {"preparation": 0.5, "duration": 0.4,
                                                        "decay": 0.2}}
    assert wait_job(client, _submit(client, other_clip))["start"] is None  # not its neighbours
    r = client.post("/jobs", json={"spec": bend_spec("x", 0.4), "start": "warm"})
    assert r.status_code == 422 and r.json()["detail"].startswith("start:")
    r = client.post("/jobs", params={"start": "cold"}, json={"spec": bend_spec("x", 0.4)})
    assert r.status_code == 422 and r.json()["detail"].startswith("start: ")
