"""`GET /cmrts/interpolate?verify=true` and `POST /refinements` over HTTP: the answer's
fields, a verified answer simulated once and then kept, a refinement that grows the family, and
the bad-input cases (4xx naming the field, nothing stored)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from application.library import library_entry
from sim.spec import parse_spec
from store import TERMINAL_STATUSES

ROOT = Path(__file__).resolve().parents[2]
BASE = np.array([0.25, 0.5, 0.45, 0.55, 0.6, 0.5, 0.75, 0.5])


@pytest.fixture
def library(repo):
    doc = yaml.safe_load((ROOT / "examples" / "fast_bend.yaml").read_text())
    for d, shift, obj in [(0.3, 0.0, 2.0), (0.4, 0.02, 2.1), (0.5, 0.04, 2.2), (0.6, 0.05, 2.3)]:
        doc["clip"]["duration"] = d
        spec = parse_spec(doc)
        params = np.clip(BASE + shift * np.array([1, -1] * 4), 0, 1)
        repo.add_cmrt(library_entry(spec, params, objective=obj, fell=False))
    return repo


def test_verified_answer_over_http_is_kept(client, library):
    r = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.45,
                                                 "verify": "true"})
    assert r.status_code == 200, r.text
    a = r.json()
    assert a["verified"] is True and a["source"] in ("interpolated", "member")
    assert a["outcome"]["cached"] is False and a["outcome"]["status"] == "done"
    assert all(n["url"].endswith(n["id"]) for n in a["neighbours"])
    if a["verdict"] != "good":
        assert a["refine"]["body"] == {"family": "bend", "parameters": {"duration": 0.45}}
    again = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.45,
                                                     "verify": "true"}).json()
    assert again["outcome"]["cached"] is True
    assert again["outcome"]["objective"] == a["outcome"]["objective"]
    plain = client.get("/cmrts/interpolate", params={"family": "bend",
                                                     "clip.duration": 0.45}).json()
    assert plain["verified"] is False and plain["key"] == "duration"
    assert "clip.duration" in plain["note"]


def test_refine_grows_the_family(client, library, repo):
    r = client.post("/refinements", json={"family": "bend", "parameters": {"duration": 0.45}})
    assert r.status_code == 422 and r.json()["detail"].startswith("basis: ")
    assert repo.list_jobs()[1] == 0
    assert client.post("/bases", json={"family": "bend", "k": 2}).status_code == 201
    r = client.post("/refinements", json={"family": "bend", "parameters": {"duration": 0.45},
                                           "max_evaluations": 30})
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["start"]["kind"] == "refine" and job["basis_id"]
    assert job["answer"]["source"] == "interpolated"
    deadline = time.monotonic() + 60
    while client.get(job["url"]).json()["status"] not in TERMINAL_STATUSES:
        assert time.monotonic() < deadline
        time.sleep(0.1)
    done = client.get(job["url"]).json()
    assert done["status"] == "stopped"  # by its stopping rules
    assert done["evaluations"] <= 30  # whole generations within the budget
    found = client.get("/cmrts", params={"family": "bend", "duration": 0.45}).json()
    assert found["total"] == 1
    a = client.get("/cmrts/interpolate", params={"family": "bend", "duration": 0.45}).json()
    assert a["exact"] and a["source"] == "refined" and a["refine"] is None
    assert client.get("/cmrts/families").json()["items"] == [{"family": "bend", "count": 5}]


@pytest.mark.parametrize("query,field", [
    ({"family": "nope", "duration": 0.45}, "family"),
    ({"family": "bend", "duration": 0.9}, "outside"),
    ({"family": "bend", "task.mass": 45}, "task.mass"),
    ({"family": "bend", "mass": 45}, "mass"),
])
def test_bad_queries_are_refused(client, library, repo, query, field):
    r = client.get("/cmrts/interpolate", params={**query, "verify": "true"})
    assert r.status_code == 422 and field in r.json()["detail"], r.text
    r = client.post("/refinements", json={"family": query["family"], "parameters": {
        k: v for k, v in query.items() if k != "family"}})
    assert r.status_code == 422 and field in r.json()["detail"], r.text
    assert repo.list_jobs()[1] == 0 and repo.list_cmrts()[1] == 4


def test_refine_body_is_checked(client, library, repo):
    for body, field in [({"family": "bend"}, "parameters"),
                        ({"family": "bend", "parameters": {"duration": 0.45}, "x": 1}, "x"),
                        ({"family": "bend", "parameters": {"duration": 0.45},
                          "max_evaluations": 0}, "max_evaluations")]:
        r = client.post("/refinements", json=body)
        assert r.status_code == 422 and field in r.text, r.text
    assert repo.list_jobs()[1] == 0
