"""The HTTP edge against a stranger and a hostile page: token, CSRF, Host header, health
detail, security headers, an offline /docs."""

from __future__ import annotations

import logging
import re

import pytest
from fastapi.testclient import TestClient
from svc_helpers import LOCAL, bend_spec

from cmrt.settings import Settings
from service import security
from service.app import create_app
from service.security import PAGE_CSP, allowed_hosts, host_allowed, host_warning

TOKEN = "s3cret-token"


def _client(settings, repo, executor, config, **overrides):
    s = config.model_copy(update=overrides)
    return TestClient(create_app(s, repo=repo, executor=executor, run_drivers=False),
                      base_url=LOCAL)


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
        r = c.post("/jobs", json={"spec": bend_spec()}, headers=headers)
        assert r.status_code == 401, r.text
        assert r.headers["www-authenticate"].startswith("Bearer")
        assert r.json()["detail"].startswith("authorization: ")
        assert c.get("/jobs", headers=headers).status_code == 401
        assert c.post("/jobs/x/cancel", headers=headers).status_code == 401
    r = c.post("/jobs", json={"spec": bend_spec()}, headers=_auth())
    assert r.status_code == 202
    assert c.get("/jobs", headers=_auth()).json()["total"] == 1
    for path in ("/health", "/dashboard", "/dashboard/jobs/x", "/dashboard/library", "/docs",
                 "/openapi.json", "/static/dash/job.js"):
        assert c.get(path).status_code == 200, path


def test_public_reads_open_get_only(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config, api_public_reads=True,
                 api_token=Settings(api_token=TOKEN).api_token) as c:
        assert c.get("/jobs").status_code == 200
        assert c.post("/jobs", json={"spec": bend_spec()}).status_code == 401
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

    r = open_client.post("/jobs", content=json.dumps({"spec": bend_spec()}).encode(),
                         headers={"content-type": "application/json; charset=utf-8"})
    assert r.status_code == 202


def test_cross_site_state_change_is_refused(open_client):
    job = open_client.post("/jobs", json={"spec": bend_spec()}).json()["id"]
    r = open_client.post(f"/jobs/{job}/cancel", headers={"sec-fetch-site": "cross-site"})
    assert r.status_code == 403 and r.json()["detail"].startswith("origin: ")
    assert open_client.get(f"/jobs/{job}").json()["cancel_requested"] is False
    assert open_client.post(f"/jobs/{job}/cancel",
                            headers={"sec-fetch-site": "same-origin"}).status_code == 202


@pytest.mark.parametrize("headers", [
    {"sec-fetch-site": "same-site", "origin": "http://127.0.0.1:9999"},
    {"origin": "http://127.0.0.1:9999"},  # a browser without Sec-Fetch-* headers
    {"origin": "http://localhost:8001"},  # the same host, another port
    {"origin": "https://localhost"},  # another scheme
    {"origin": "null"},  # a sandboxed frame, a file: page
    {"sec-fetch-site": "same-site"},
])
def test_another_origin_cannot_change_state(open_client, headers):
    job = open_client.post("/jobs", json={"spec": bend_spec()}).json()["id"]
    r = open_client.post(f"/jobs/{job}/cancel", headers={**headers, "content-type": "text/plain"},
                         content=b"x")
    assert r.status_code == 403, r.text
    assert r.json()["detail"].startswith("origin: requests that change state from another "
                                         "origin are refused ("), r.text
    assert open_client.get(f"/jobs/{job}").json()["cancel_requested"] is False
    r = open_client.post("/jobs", json={"spec": bend_spec("other")}, headers=headers)
    assert r.status_code == 403 and open_client.get("/jobs").json()["total"] == 1
    # Reads are not state changes: a page may link to them.
    assert open_client.get(f"/jobs/{job}", headers=headers).status_code == 200


def test_the_own_origin_changes_state(settings, config, repo, local_executor, open_client):
    job = open_client.post("/jobs", json={"spec": bend_spec()},
                           headers={"origin": "http://localhost",
                                    "sec-fetch-site": "same-origin"}).json()["id"]
    assert open_client.post(f"/jobs/{job}/cancel",
                            headers={"origin": "http://localhost"}).status_code == 202
    # Behind a proxy the public URL's origin is the service's own, whatever (allowed) name the
    # proxy puts in Host.
    with _client(settings, repo, local_executor, config, allowed_hosts=["10.0.0.5"],
                 public_url="https://cmrt.example/api") as c:
        assert c.post("/jobs", json={"spec": bend_spec("b")}, headers={
            "origin": "https://cmrt.example", "host": "10.0.0.5:8000"}).status_code == 202
        assert c.post("/jobs", json={"spec": bend_spec("c")}, headers={
            "origin": "https://evil.example", "host": "10.0.0.5:8000"}).status_code == 403


def test_head_is_served_wherever_get_is(closed_client, repo):
    c = closed_client
    for path in ("/health", "/", "/openapi.json", "/docs", "/dashboard", "/jobs", "/cmrts"):
        get = c.get(path, headers=_auth())
        head = c.head(path, headers=_auth())
        assert head.status_code == get.status_code == 200, (path, head.status_code)
        assert head.content == b"" and head.headers["content-type"] == get.headers[
            "content-type"], path
        assert head.headers["content-length"] == get.headers["content-length"], path
    assert c.head("/jobs").status_code == 401  # the token is needed as on GET
    r = c.head("/jobs/nosuchjob", headers=_auth())
    assert r.status_code == 404 and r.content == b""
    assert "HEAD" in c.options("/jobs/x").headers["allow"]
    assert c.head("/links", headers=_auth()).status_code == 405  # no GET there


def test_bidirectional_controls_are_refused(open_client):
    for field, value in (("family", "bend\u202e"), ("family", "\u2066x\u2069"),
                         ("name", "a\u200fb")):
        r = open_client.post("/jobs", json={"spec": {**bend_spec(), field: value}})
        assert r.status_code == 422, r.text
        assert r.json()["detail"].startswith(f"spec: {field}: "), r.text
    r = open_client.post("/jobs", json={"spec": {**bend_spec(), "family": "bend\u202e"}})
    assert "control character '\\u202e' not allowed" in r.json()["detail"]
    assert open_client.get("/jobs").json()["total"] == 0


def test_a_404_quotes_the_id_it_echoes(open_client):
    for raw, shown in (("%FF%FE", "'\\ufffd\\ufffd'"), ("caf%C3%A9", "'caf\\xe9'"),
                       ("abc", "'abc'")):
        r = open_client.get(f"/jobs/{raw}")
        assert r.status_code == 404 and r.json()["detail"] == f"job {shown} not found", r.text
        assert r.text.isascii()
    assert open_client.get("/cmrts/%FF").json()["detail"] == "CMRT '\\ufffd' not found"


def test_no_host_header_reflection(settings, config, repo, local_executor):
    other = {"host": "other.example:666"}  # an allowed name, never echoed into URLs
    with _client(settings, repo, local_executor, config, allowed_hosts=["other.example"]) as c:
        r = c.post("/jobs", json={"spec": bend_spec()}, headers=other)
        job = r.json()["id"]
        assert r.headers["location"] == f"/jobs/{job}" and r.json()["url"] == f"/jobs/{job}"
        for resp in (c.get(f"/jobs/{job}", headers=other), c.get("/jobs", headers=other),
                     c.get("/", headers=other), c.post(f"/jobs/{job}/cancel", headers=other)):
            assert resp.status_code in (200, 202) and "other" not in resp.text, resp.text
        assert c.get("/", headers=other).json()["jobs"] == "/jobs"
        refused = c.get("/jobs", headers={"host": "evil.example:666"})
        assert refused.status_code == 400 and "evil" not in refused.text, refused.text


def test_public_url_is_the_base_of_returned_urls(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config,
                 public_url="https://cmrt.example/api") as c:
        r = c.post("/jobs", json={"spec": bend_spec()}, headers={"host": "localhost:9"})
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


# ---- DNS rebinding: the Host allowlist ---------------------------------------------------
#: What a page of evil.example sends once its name resolves to this machine: to the browser
#: the API is then same-origin, so only the Host header tells the request apart.
REBOUND = {"host": "evil.example:8000", "origin": "http://evil.example:8000",
           "sec-fetch-site": "same-origin"}
HOST_REFUSED = ("host: the Host header names no host of this service (loopback, the bind "
                "address, CMRT_PUBLIC_URL's host or CMRT_ALLOWED_HOSTS); a page whose name was "
                "rebound to this address is refused")


def _refused(r):
    assert r.status_code == 400, r.text
    assert r.headers["content-type"] == "application/json"
    assert r.json() == {"detail": HOST_REFUSED}  # a reason and no data


def test_a_rebound_page_reads_and_writes_nothing(open_client, repo):
    job = open_client.post("/jobs", json={"spec": bend_spec()}).json()["id"]
    _refused(open_client.get("/jobs", headers=REBOUND))
    _refused(open_client.get(f"/jobs/{job}", headers=REBOUND))
    _refused(open_client.get("/cmrts", headers=REBOUND))
    _refused(open_client.post("/bases", json={"family": "bend", "k": 1}, headers=REBOUND))
    _refused(open_client.post("/jobs", json={"spec": bend_spec("rebound")}, headers=REBOUND))
    _refused(open_client.post(f"/jobs/{job}/cancel", headers=REBOUND))
    _refused(open_client.options("/jobs", headers=REBOUND))
    _refused(open_client.get("/health", headers=REBOUND))
    head = open_client.head("/jobs", headers=REBOUND)
    assert head.status_code == 400 and head.content == b""
    assert repo.list_jobs()[1] == 1 and repo.list_bases(None)[1] == 0
    assert open_client.get(f"/jobs/{job}").json()["cancel_requested"] is False


@pytest.mark.parametrize("host", ["localhost", "localhost:8000", "LOCALHOST:1", "127.0.0.1",
                                  "127.0.0.1:8000", "127.3.2.1:80", "[::1]", "[::1]:8000",
                                  "localhost.:8000"])
def test_loopback_names_are_answered(open_client, host):
    origin = f"http://{host}"
    same = {"host": host, "origin": origin, "sec-fetch-site": "same-origin"}
    assert open_client.get("/jobs", headers=same).status_code == 200
    # the dashboard's request
    r = open_client.post("/jobs", json={"spec": bend_spec()}, headers=same)
    assert r.status_code == 202, r.text


@pytest.mark.parametrize("host", ["evil.example", "evil.example:8000", "localhost.evil.example",
                                  "127.0.0.1.evil.example", "10.0.0.5:8000", "[::2]:8000",
                                  "a b", "localhost:notaport", "user@localhost", "localhost/x",
                                  ""])
def test_other_hosts_are_refused(open_client, host):
    _refused(open_client.get("/jobs", headers={"host": host}))


def test_configured_names_are_answered(settings, config, repo, local_executor):
    with _client(settings, repo, local_executor, config, public_url="https://cmrt.example/api",
                 allowed_hosts=Settings(allowed_hosts="cmrt.lan, API ,[fd00::5]").allowed_hosts,
                 api_host="10.0.0.7") as c:
        for host in ("cmrt.example", "CMRT.example:443", "cmrt.lan:8000", "api:8000",
                     "[fd00::5]:8000", "10.0.0.7:8000", "localhost:8000"):
            assert c.get("/jobs", headers={"host": host}).status_code == 200, host
        origin = {"host": "api:8000", "origin": "http://api:8000",
                  "sec-fetch-site": "same-origin"}
        assert c.post("/jobs", json={"spec": bend_spec()}, headers=origin).status_code == 202
        for host in ("evil.example", "cmrt.example.evil", "lan", "10.0.0.8"):
            _refused(c.get("/jobs", headers={"host": host}))
    with _client(settings, repo, local_executor, config, allowed_hosts=["*"]) as c:
        assert c.get("/jobs", headers=REBOUND).status_code == 200  # the check is off


def test_allowed_hosts_setting(monkeypatch):
    monkeypatch.setenv("CMRT_ALLOWED_HOSTS", " cmrt.lan,API, [::5] ,,")
    assert Settings().allowed_hosts == ["cmrt.lan", "api", "::5"]
    for bad in ("http://cmrt.lan", "cmrt.lan:8000", "cmrt.lan/x", "[::1]:80", "a b"):
        monkeypatch.setenv("CMRT_ALLOWED_HOSTS", bad)
        with pytest.raises(ValueError, match="allowed_hosts") as err:
            Settings()
        assert "is not a host name or address" in str(err.value)


def test_a_wildcard_bind_without_names_warns():
    assert host_warning(Settings(api_host="0.0.0.0")).startswith("bound to every interface")
    assert host_warning(Settings(api_host="::")) is not None
    assert host_warning(Settings(api_host="0.0.0.0", allowed_hosts=["cmrt.lan"])) is None
    assert host_warning(Settings(api_host="0.0.0.0", public_url="https://cmrt.example")) is None
    assert host_warning(Settings()) is None  # loopback bind: loopback names suffice
    assert host_allowed(None, allowed_hosts(Settings()))  # HTTP/1.0 without Host: no browser


def test_allow_sets_are_remembered_per_path_within_a_bound(config, repo, local_executor,
                                                           monkeypatch):
    """The edge remembers each path's Allow set (the routes are fixed) and forgets the oldest
    paths past ALLOW_MEMO_PATHS: the same answers as probing the routes, bounded memory."""
    monkeypatch.setattr(security, "ALLOW_MEMO_PATHS", 4)
    app = create_app(config, repo=repo, executor=local_executor, run_drivers=False)
    edge = security.HttpEdge(app, app=app, settings=config)
    paths = ["/health", "/jobs", *(f"/jobs/j{i}" for i in range(6)), "/jobs/j0/cancel", "/nope",
             "/health", "/cmrts/interpolate"]
    for path in paths:
        scope = {"type": "http", "path": path, "root_path": "", "method": "GET"}
        assert edge.allowed(scope) == security.allowed_methods(app, scope), path
        assert len(edge._allow) <= 4
    assert edge.allowed({"type": "http", "path": "/jobs/j5", "root_path": "",
                         "method": "GET"}) == ["GET", "HEAD", "OPTIONS"]
    assert edge.allowed({"type": "http", "path": "/nope", "root_path": "", "method": "GET"}) == []
