"""The replay routes: GET /cmrts/{id}/replay[.json], GET /jobs/{id}/replay[.json] and
POST /simulations/replay[.json] simulate real clips (ODE, the momentum controller) in the API's
simulation pool; the JSON is sim.replay's document and agrees with POST /simulations; bad ids
and states are 404 / 409, bad bodies and parameters 422."""

from __future__ import annotations

import json

import pytest
from svc_helpers import QUIET, bend_spec, wait_job

from sim.physics import DT
from sim.recording import FRAME_EVERY

FRAME_RATE = 1.0 / (FRAME_EVERY * DT)


@pytest.fixture
def finished_job(client):
    job_id = client.post("/jobs", json={"spec": bend_spec("bend_r", 0.3)}).json()["id"]
    return wait_job(client, job_id)


def test_job_replay_json_matches_the_what_if_simulation(client, finished_job):
    job = finished_job
    r = client.get(f"/jobs/{job['id']}/replay.json")
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["schema"] == "cmrt-replay/1" and doc["spec"]["name"] == "bend_r"
    flat, best = doc["clips"]
    assert flat["label"].startswith("no anticipation") and best["cmrt"]["source"] == "job"
    n = round(0.8 * FRAME_RATE)  # clip length 0.3 + 0.3 + 0.2 s
    assert flat["frames"] == best["frames"] == len(best["poses"]) == n
    assert len(best["poses"][0]) == 3 * len(doc["bodies"])
    assert any(abs(v) > 1e-4 for v in best["plots"]["cmrt_dx"])
    assert all(v == 0.0 for v in flat["plots"]["cmrt_dx"])
    # The same candidate through POST /simulations: the same objective and fall.
    sim = client.post("/simulations", json={"spec": job["spec"], "traces": False,
                                            "cmrt": {"source": "job", "id": job["id"]}}).json()
    assert best["outcome"]["objective"] == pytest.approx(sim["objective"], abs=1e-6)
    assert best["outcome"]["fell"] == sim["fell"]
    one = client.get(f"/jobs/{job['id']}/replay.json?compare=false").json()
    assert [c["label"] for c in one["clips"]] == ["with the CMRT"]


def test_html_replays_are_self_contained_with_a_hash_csp(client, finished_job):
    for url in (f"/jobs/{finished_job['id']}/replay", f"/cmrts/{finished_job['cmrt_id']}/replay"):
        r = client.get(url)
        assert r.status_code == 200, r.text
        assert r.headers["content-type"].startswith("text/html")
        csp = r.headers["content-security-policy"]
        assert "script-src 'sha256-" in csp and "default-src 'none'" in csp
        assert "unsafe-inline" not in csp
        html = r.text
        assert '<script id="replay-data" type="application/json">' in html
        assert "src=" not in html and "href=" not in html  # nothing loaded from outside
        data = html.split('type="application/json">', 1)[1].split("</script>", 1)[0]
        assert len(json.loads(data)["clips"]) == 2


def test_cmrt_replay_json(client, finished_job):
    r = client.get(f"/cmrts/{finished_job['cmrt_id']}/replay.json")
    assert r.status_code == 200, r.text
    clips = r.json()["clips"]
    assert clips[1]["cmrt"]["id"] == finished_job["cmrt_id"]
    assert [c["outcome"]["objective"] is not None for c in clips] == [True, True]


def test_what_if_replay(client):
    r = client.post("/simulations/replay.json", json={"spec": QUIET})
    assert r.status_code == 200, r.text
    (clip,) = r.json()["clips"]  # no CMRT: the clip without anticipation only
    assert clip["frames"] == round(0.7 * FRAME_RATE) and clip["outcome"]["fell"] is False
    h = client.post("/simulations/replay", json={"spec": QUIET, "compare": False})
    assert h.status_code == 200 and h.text.startswith("<!doctype html>")


@pytest.mark.parametrize(("method", "url", "body", "status", "needle"), [
    ("get", "/jobs/nope/replay", None, 404, "nope"),
    ("get", "/jobs/nope/replay.json", None, 404, "nope"),
    ("get", "/cmrts/nope/replay", None, 404, "nope"),
    ("get", "/cmrts/nope/replay.json", None, 404, "nope"),
    ("get", "/jobs/nope/replay.json?compare=maybe", None, 422, "compare"),
    ("post", "/simulations/replay", {"spec": QUIET, "compare": "yes"}, 422, "compare: "),
    ("post", "/simulations/replay.json", {"spec": {**QUIET, "clip": {"duration": -1}}}, 422,
     "spec.clip.duration: "),
    ("post", "/simulations/replay.json", {"spec": QUIET, "cmrt": {"source": "job",
                                                                  "id": "nope"}},
     422, "cmrt.id: no job 'nope'"),
    ("post", "/simulations/replay.json", {"spec": QUIET, "frames": True}, 422,
     "frames: Extra inputs are not permitted"),
])
def test_bad_ids_and_requests(http_client, method, url, body, status, needle):
    r = getattr(http_client, method)(url, **({} if body is None else {"json": body}))
    assert r.status_code == status, r.text
    assert needle in r.json()["detail"], r.json()["detail"]


def test_job_without_a_candidate_is_409(http_client, repo):
    from sim.spec import parse_spec

    spec = parse_spec(bend_spec())
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=0)
    for suffix in ("replay", "replay.json"):
        r = http_client.get(f"/jobs/{job.id}/{suffix}")
        assert r.status_code == 409, r.text
        assert r.json()["detail"] == f"job {job.id!r}: no best candidate yet (queued)"
