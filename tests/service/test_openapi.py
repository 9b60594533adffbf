"""The OpenAPI document says exactly what the API does."""

from __future__ import annotations

import json

import pytest

from service.openapi import REF_PREFIX
from service.schemas import BASIS_EXAMPLE, JOB_EXAMPLE
from sim.spec import parse_spec


@pytest.fixture
def client(http_client):
    return http_client


def _refs(node):
    if isinstance(node, dict):
        yield from ([node["$ref"]] if "$ref" in node else [])
        for v in node.values():
            yield from _refs(v)
    elif isinstance(node, list):
        for v in node:
            yield from _refs(v)


def test_every_reference_resolves(client):
    doc = client.get("/openapi.json").json()
    text = json.dumps(doc)
    assert "$defs" not in text
    refs = set(_refs(doc))
    assert REF_PREFIX + "CharacterRef" in refs
    for r in refs:
        assert r.startswith(REF_PREFIX) and r.removeprefix(REF_PREFIX) in \
            doc["components"]["schemas"], r


def test_errors_are_documented_as_they_are_sent(client):
    doc = client.get("/openapi.json").json()
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    problem = {"$ref": REF_PREFIX + "Problem"}
    for path, item in doc["paths"].items():
        for method, op in item.items():
            codes = op["responses"]
            assert "422" in codes, (method, path)
            for code, resp in codes.items():
                if int(code) >= 400:
                    assert resp["content"]["application/json"]["schema"] == problem
    post_jobs = doc["paths"]["/jobs"]["post"]["responses"]
    assert {"400", "403", "413", "415", "422"} <= set(post_jobs)
    assert {"404", "409"} <= set(doc["paths"]["/jobs/{job_id}/cancel"]["post"]["responses"])
    assert "503" in doc["paths"]["/health"]["get"]["responses"]
    # and the body really is {"detail": "<string>"}
    r = client.get("/jobs", params={"limit": 0})
    assert r.status_code == 422 and r.json() == {
        "detail": "limit: Input should be greater than or equal to 1"}


def test_request_bodies_are_documented(client):
    doc = client.get("/openapi.json").json()
    bases = doc["paths"]["/bases"]["post"]["requestBody"]["content"]["application/json"]
    assert bases["schema"] == {"$ref": REF_PREFIX + "BasisRequest"}
    assert bases["example"] == BASIS_EXAMPLE
    jobs = doc["paths"]["/jobs"]["post"]["requestBody"]["content"]["application/json"]
    # one envelope (a generator makes it a typed model); its spec is the task spec
    assert jobs["schema"] == {"$ref": REF_PREFIX + "JobRequest"}
    envelope = doc["components"]["schemas"]["JobRequest"]
    assert envelope["properties"]["spec"] == {"$ref": REF_PREFIX + "TaskSpec"}
    assert envelope["required"] == ["spec"]
    parse_spec(jobs["example"]["spec"], "example")  # the documented example is a valid spec
    assert client.post("/jobs", json=jobs["example"]).status_code == 202
    assert jobs["example"]["spec"] == JOB_EXAMPLE
    # one request form: the body's fields are not repeated as query parameters
    assert "parameters" not in doc["paths"]["/jobs"]["post"]
    # a family without library CMRTs has no basis to build: 404
    assert "404" in doc["paths"]["/bases"]["post"]["responses"]


@pytest.mark.parametrize(("path", "allow"), [
    ("/jobs", "GET, HEAD, OPTIONS, POST"),
    ("/jobs/abc", "GET, HEAD, OPTIONS"),
    ("/jobs/abc/cancel", "OPTIONS, POST"),
    ("/bases", "GET, HEAD, OPTIONS, POST"),
    ("/cmrts/interpolate", "GET, HEAD, OPTIONS"),
    ("/health", "GET, HEAD, OPTIONS"),
])
def test_options_and_405_name_every_method(client, path, allow):
    r = client.options(path)
    assert r.status_code == 204 and r.headers["allow"] == allow
    wrong = "DELETE"
    r = client.request(wrong, path)
    assert r.status_code == 405 and r.headers["allow"] == allow
    assert r.json()["detail"] == f"method: DELETE is not allowed on {path} (allowed: {allow})"


def test_unknown_path_is_404_for_every_method(client):
    assert client.options("/nope").status_code == 404
    assert client.delete("/nope").status_code == 404
