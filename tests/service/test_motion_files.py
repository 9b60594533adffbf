"""A job's motion files: GET /jobs/{id}/motion.bvh and .csv simulate the job's best candidate
(a real clip in the API's simulation pool) and answer what sim.export writes of it, as an
attachment; the replay document carries the same files; 404 while there is no candidate,
422 for a bad frame rate; a signed link opens them without the token header."""

from __future__ import annotations

import csv
import io
from urllib.parse import urlsplit

import pytest
from bvh_helpers import read
from fastapi.testclient import TestClient
from svc_helpers import LOCAL, bend_spec, wait_job

from cmrt.settings import Settings
from optim.spline import decode
from service.app import create_app
from sim.export import export_text
from sim.rollout import evaluate
from sim.spec import parse_spec

TOKEN = "s3cret-token"


@pytest.fixture
def finished_job(client):
    job_id = client.post("/jobs", json={"spec": bend_spec("bend_m", 0.3)}).json()["id"]
    return wait_job(client, job_id)


def test_the_motion_files_are_the_best_candidates_clip(client, finished_job):
    job = finished_job
    spec = parse_spec(job["spec"])
    ev = evaluate(spec, decode(spec, job["best_params"]), traces=True)
    ch = spec.load_character()
    r = client.get(f"/jobs/{job['id']}/motion.bvh")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "text/plain; charset=utf-8"
    assert r.headers["content-disposition"] == \
        f'attachment; filename="bend_m-{job["id"]}.bvh"'
    assert r.text == export_text(ch, ev, "bvh", 60.0)
    assert read(r.text).nframes == 48  # a 0.8 s clip at 60 fps: frames 0 .. 47 (0.783 s)
    c = client.get(f"/jobs/{job['id']}/motion.csv?fps=25")
    assert c.status_code == 200 and c.headers["content-type"] == "text/csv; charset=utf-8"
    assert c.text == export_text(ch, ev, "csv", 25.0)
    rows = list(csv.reader(io.StringIO(c.text)))
    assert rows[0][:4] == ["t", "root_x", "root_y", "root_angle"] and len(rows) == 1 + 20
    # The replay of the job carries the same clip's files, for the player's downloads.
    doc = client.get(f"/jobs/{job['id']}/replay.json").json()
    flat, best = doc["clips"]
    assert best["motion"] == {"fps": 60.0, "bvh": r.text,
                              "csv": export_text(ch, ev, "csv", 60.0)}
    assert flat["motion"]["bvh"] == export_text(ch, evaluate(spec, None, traces=True), "bvh")


@pytest.mark.parametrize(("query", "needle"), [
    ("fps=0", "fps: "), ("fps=1001", "fps: "), ("fps=nan", "fps: "), ("fps=abc", "fps: "),
])
def test_a_bad_frame_rate_is_422(http_client, repo, query, needle):
    spec = parse_spec(bend_spec())
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=0)
    for fmt in ("bvh", "csv"):
        r = http_client.get(f"/jobs/{job.id}/motion.{fmt}?{query}")
        assert r.status_code == 422, r.text
        assert r.json()["detail"].startswith(needle), r.json()["detail"]


def test_no_job_or_no_candidate_is_404(http_client, repo):
    spec = parse_spec(bend_spec())
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=0)
    for fmt in ("bvh", "csv"):
        r = http_client.get(f"/jobs/{job.id}/motion.{fmt}")
        assert r.status_code == 404, r.text
        assert r.json()["detail"].startswith(f"job {job.id!r}: no best candidate yet (queued)")
        r = http_client.get(f"/jobs/nope/motion.{fmt}")
        assert r.status_code == 404 and "nope" in r.json()["detail"]


def test_a_signed_link_opens_a_motion_file(config, repo, local_executor):
    s = config.model_copy(update={"api_token": Settings(api_token=TOKEN).api_token})
    spec = parse_spec(bend_spec("linked"))
    job = repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                          family=spec.family_name, task=spec.task_type, seed=0)
    with TestClient(create_app(s, repo=repo, executor=local_executor, run_drivers=False),
                    base_url=LOCAL) as c:
        path = f"/jobs/{job.id}/motion.bvh"
        assert c.get(path).status_code == 401
        r = c.post("/links", json={"path": path},
                   headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 201, r.text
        url = r.json()["url"]
        assert urlsplit(url).path == path
        # Past the edge: the route answers (no candidate yet), not the edge's 401.
        assert c.get(url).status_code == 404
        # Not for another file of the job: the signature names its path.
        assert c.get(url.replace("motion.bvh", "motion.csv")).status_code == 401
