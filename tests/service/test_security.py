"""The HTTP edge against a stranger and a hostile page: token, CSRF, Host header, health
detail, security headers, an offline /docs."""

from __future__ import annotations

import logging
import re

import pytest
from fastapi.testclient import TestClient
from svc_helpers import bend_spec

from cmrt.settings import Settings
from service.app import create_app
from service.security import PAGE_CSP

TOKEN = "s3cret-token"


def _client(settings, repo, executor, config, **overrides):
    s = config.model_copy(update=overrides)
    return TestClient(create_app(s, repo=repo, executor=executor, run_drivers=False))


@pytest.fixture
def open_client(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config) as c:
        yield c


@pytest.fixture
def closed_client(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config,
                 api_token=Settings(api_token=TOKEN).api_token) as c:
        yield c


def _auth(token=TOKEN):
    return {"Authorization": f"Bearer {token}"}


def test_settings_read_the_token_from_the_environment(monkeypatch):
    monkeypatch.setenv("CMRT_API_TOKEN", TOKEN)
    monkeypatch.setenv("CMRT_API_PUBLIC_READS", "true")
    s = Settings()
    assert s.api_token.get_secret_value() == TOKEN and s.api_public_reads
    assert TOKEN not in repr(s)
    monkeypatch.setenv("CMRT_API_TOKEN", "")
    assert Settings().api_token is None


def test_token_guards_writes_and_reads(closed_client):
    c = closed_client
    for headers in ({}, _auth("wrong"), {"Authorization": TOKEN}):
        r = c.post("/jobs", json=bend_spec(), headers=headers)
        assert r.status_code == 401, r.text
        assert r.headers["www-authenticate"].startswith("Bearer")
        assert r.json()["detail"].startswith("authorization: ")
        assert c.get("/jobs", headers=headers).status_code == 401
        assert c.post("/jobs/x/cancel", headers=headers).status_code == 401
    r = c.post("/jobs", json=bend_spec(), headers=_auth())
    assert r.status_code == 202
    assert c.get("/jobs", headers=_auth()).json()["total"] == 1
    for path in ("/health", "/dashboard", "/dashboard/jobs/x", "/dashboard/library", "/docs",
                 "/openapi.json", "/static/dash/job.js"):
        assert c.get(path).status_code == 200, path


def test_public_reads_open_get_only(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config, api_public_reads=True,
                 api_token=Settings(api_token=TOKEN).api_token) as c:
        assert c.get("/jobs").status_code == 200
        assert c.post("/jobs", json=bend_spec()).status_code == 401
        assert c.post("/bases", json={"family": "bend"}).status_code == 401


def test_document_declares_the_token(closed_client, open_client):
    doc = closed_client.get("/openapi.json").json()
    assert doc["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    op = doc["paths"]["/jobs"]["post"]
    assert op["security"] == [{"bearer": []}] and "401" in op["responses"]
    assert "security" not in doc["paths"]["/health"]["get"]
    plain = open_client.get("/openapi.json").json()
    assert "securitySchemes" not in plain["components"]
    assert "401" not in plain["paths"]["/jobs"]["post"]["responses"]


@pytest.mark.parametrize("ctype", ["text/plain", "application/x-www-form-urlencoded",
                                   "multipart/form-data; boundary=x", None])
def test_bodies_must_be_json(open_client, ctype):
    """A cross-origin page's no-cors fetch can send these without a preflight."""
    import json

    headers = {"content-type": ctype} if ctype else {}
    for path in ("/jobs", "/bases"):
        r = open_client.post(path, content=json.dumps(bend_spec()).encode(), headers=headers)
        assert r.status_code == 415, r.text
        assert r.json()["detail"].startswith("content-type: must be application/json")
    assert open_client.get("/jobs").json()["total"] == 0


def test_json_with_charset_is_accepted(open_client):
    import json

    r = open_client.post("/jobs", content=json.dumps(bend_spec()).encode(),
                         headers={"content-type": "application/json; charset=utf-8"})
    assert r.status_code == 202


def test_cross_site_state_change_is_refused(open_client):
    job = open_client.post("/jobs", json=bend_spec()).json()["id"]
    r = open_client.post(f"/jobs/{job}/cancel", headers={"sec-fetch-site": "cross-site"})
    assert r.status_code == 403 and r.json()["detail"].startswith("origin: ")
    assert open_client.get(f"/jobs/{job}").json()["cancel_requested"] is False
    assert open_client.post(f"/jobs/{job}/cancel",
                            headers={"sec-fetch-site": "same-origin"}).status_code == 202


def test_no_host_header_reflection(open_client):
    evil = {"host": "evil.example:666"}
    r = open_client.post("/jobs", json=bend_spec(), headers=evil)
    job = r.json()["id"]
    assert r.headers["location"] == f"/jobs/{job}" and r.json()["url"] == f"/jobs/{job}"
    for resp in (open_client.get(f"/jobs/{job}", headers=evil),
                 open_client.get("/jobs", headers=evil),
                 open_client.get("/", headers=evil),
                 open_client.post(f"/jobs/{job}/cancel", headers=evil)):
        assert "evil" not in resp.text, resp.text
    assert open_client.get("/", headers=evil).json()["jobs"] == "/jobs"


def test_public_url_is_the_base_of_returned_urls(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config,
                 public_url="https://cmrt.example/api") as c:
        r = c.post("/jobs", json=bend_spec(), headers={"host": "evil.example"})
        job = r.json()["id"]
        assert r.headers["location"] == f"https://cmrt.example/api/jobs/{job}"
        assert c.get(f"/jobs/{job}").json()["links"]["cancel"] == \
            f"https://cmrt.example/api/jobs/{job}/cancel"


def test_public_url_must_be_http(tmp_path):
    with pytest.raises(ValueError, match="public_url"):
        Settings(data_dir=tmp_path, public_url="javascript:alert(1)")


def test_health_503_gives_the_state_only(settings, config, repo, local_executor, caplog):
    with _client(settings, repo, local_executor, config) as c:
        assert c.get("/health").status_code == 200
        with repo.engine.begin() as conn:  # the database loses its tables
            from sqlalchemy import text

            conn.execute(text("DROP TABLE jobs"))
        with caplog.at_level(logging.ERROR, logger="cmrt.service.health"):
            r = c.get("/health")
    assert r.status_code == 503
    body = r.json()
    assert body["status"] == "degraded" and body["database"] == "error"
    assert not re.search(r"(?i)select|sqlite|no such table|from jobs", r.text), r.text
    assert "no such table" in caplog.text  # the detail is in the log


def test_security_headers(open_client):
    for path in ("/jobs", "/health", "/nope", "/docs", "/dashboard"):
        r = open_client.get(path)
        assert r.headers["x-content-type-options"] == "nosniff", path
        assert r.headers["x-frame-options"] == "DENY", path
        assert "frame-ancestors 'none'" in r.headers["content-security-policy"], path
    for path in ("/dashboard", "/dashboard/jobs/x", "/dashboard/library"):
        page = open_client.get(path)
        assert page.headers["content-security-policy"] == PAGE_CSP, path
        assert "<script>" not in page.text and "style=" not in page.text  # nothing inline


def test_docs_are_served_from_the_project(open_client):
    page = open_client.get("/docs")
    assert page.status_code == 200
    assert not re.search(r"https?://", page.text), "the docs page must not load from a CDN"
    srcs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert "/static/swagger-ui/swagger-ui-bundle.js" in srcs
    for src in srcs:
        r = open_client.get(src)
        assert r.status_code == 200 and len(r.content) > 0, src
    assert "SwaggerUIBundle" in open_client.get("/static/docs.js").text
