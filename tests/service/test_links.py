"""Signed replay links (service.links, POST /links): with a token set and reads closed, a
replay page opens with a valid, unexpired signature for exactly its path, and with nothing
else; the JSON endpoints keep needing the header."""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

import pytest
from fastapi.testclient import TestClient
from svc_helpers import LOCAL, bend_spec

from cmrt.settings import Settings
from service import links
from service.app import create_app
from sim.spec import parse_spec

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def closed(config, repo, local_executor):
    s = config.model_copy(update={"api_token": Settings(api_token=TOKEN).api_token})
    with TestClient(create_app(s, repo=repo, executor=local_executor, run_drivers=False),
                    base_url=LOCAL) as c:
        yield c


@pytest.fixture
def open_(config, repo, local_executor):
    with TestClient(create_app(config, repo=repo, executor=local_executor,
                               run_drivers=False), base_url=LOCAL) as c:
        yield c


@pytest.fixture
def job_id(repo) -> str:
    """A queued job (no best candidate yet: its replay page answers 409)."""
    spec = parse_spec(bend_spec("linked"))
    return repo.create_job(spec.model_dump(mode="json"), name=spec.name,
                           family=spec.family_name, task=spec.task_type).id


def _mint(client, path: str) -> str:
    r = client.post("/links", json={"path": path}, headers=AUTH)
    assert r.status_code == 201, r.text
    return r.json()["url"]


def test_a_signed_link_opens_its_replay_page_only(closed, job_id):
    path = f"/jobs/{job_id}/replay"
    assert closed.get(path).status_code == 401
    url = _mint(closed, path)
    q = parse_qs(urlsplit(url).query)
    assert urlsplit(url).path == path and set(q) == {"expires", "signature"}
    # Past the edge: the route answers (the job has no best candidate yet), not the edge's 401;
    # HEAD as GET.
    r = closed.get(url)
    assert r.status_code == 409, r.text
    assert closed.head(url).status_code == 409
    # The signature covers the whole query: a parameter added or changed voids it.
    for extra in ("&compare=false", "&compare=true", "&x=1", "&expires=1"):
        r = closed.get(url + extra)
        assert r.status_code == 401, (extra, r.text)
    # The same signature on another path, on the JSON document, or on a write: refused.
    query = urlsplit(url).query
    for other in ("/jobs/otherjob/replay", f"/jobs/{job_id}/replay.json", "/jobs"):
        assert closed.get(f"{other}?{query}").status_code == 401, other
    assert closed.post(f"/jobs/{job_id}/cancel?{query}").status_code == 401


def test_links_are_minted_for_existing_ids_only(closed, job_id):
    for path in ("/jobs/nosuchjob/replay", "/cmrts/nosuchcmrt/replay"):
        r = closed.post("/links", json={"path": path}, headers=AUTH)
        assert r.status_code == 404, r.text
        assert r.json()["detail"] in ("job 'nosuchjob' not found",
                                       "CMRT 'nosuchcmrt' not found")
    assert closed.post("/links", json={"path": f"/jobs/{job_id}/replay"},
                       headers=AUTH).status_code == 201


def test_the_documented_path_pattern_is_the_rule(closed):
    import re

    schema = closed.get("/openapi.json").json()["components"]["schemas"]["LinkRequest"]
    pattern = re.compile(schema["properties"]["path"]["pattern"])
    for good in ("/jobs/a/replay", "/cmrts/" + "x" * 64 + "/replay", "/jobs/a.b_c~d-e/replay"):
        assert pattern.search(good) and links.SIGNABLE.fullmatch(good), good
    for bad in ("/jobs/x/replay.json", "/jobs//replay", "/jobs/" + "x" * 65 + "/replay",
                "/jobs/x/replay/", "x/jobs/a/replay"):
        assert not pattern.search(bad) and not links.SIGNABLE.fullmatch(bad), bad


def test_expired_or_tampered_signatures_are_refused(closed, job_id):
    path = f"/jobs/{job_id}/replay"
    url, expires = links.sign(TOKEN, path, now=1_000.0)  # expired long ago
    assert closed.get(url).status_code == 401
    fresh = _mint(closed, path)
    sig = parse_qs(urlsplit(fresh).query)["signature"][0]
    flipped = ("0" if sig[0] != "0" else "1") + sig[1:]
    assert closed.get(fresh.replace(sig, flipped)).status_code == 401
    assert closed.get(fresh.replace("expires=", "expires=9")).status_code == 401
    wrong_key, _ = links.sign("another-token", path)
    assert closed.get(wrong_key).status_code == 401
    assert closed.get(fresh + "&signature=" + sig).status_code == 401  # two signatures


def test_verify_checks_path_expiry_and_key():
    url, expires = links.sign(TOKEN, "/jobs/j1/replay", now=100.0)
    query = urlsplit(url).query
    assert expires == 100 + links.LINK_SECONDS
    assert links.verify(TOKEN, "/jobs/j1/replay", query, now=expires)
    assert not links.verify(TOKEN, "/jobs/j1/replay", query, now=expires + 1)
    assert not links.verify(TOKEN, "/jobs/j2/replay", query, now=100.0)
    assert not links.verify("", "/jobs/j1/replay", query, now=100.0)
    assert not links.verify(TOKEN, "/jobs/j1/replay", "", now=100.0)


def test_minting_needs_the_token_and_a_replay_path(closed):
    assert closed.post("/links", json={"path": "/jobs/x/replay"}).status_code == 401
    for bad in ("/jobs", "/jobs/x/replay.json", "/jobs/x/replay/../cancel",
                "https://evil.example/jobs/x/replay", "/jobs/" + "x" * 65 + "/replay"):
        r = closed.post("/links", json={"path": bad}, headers=AUTH)
        assert r.status_code == 422, (bad, r.text)
        assert r.json()["detail"].startswith("path: "), r.text
    r = closed.post("/links", json={"path": "/jobs/x/replay", "ttl": 5}, headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"].startswith("ttl: "), r.text


def test_without_a_token_the_link_is_the_plain_path(open_, job_id):
    r = open_.post("/links", json={"path": f"/jobs/{job_id}/replay"})
    assert r.status_code == 201, r.text
    assert r.json() == {"url": f"/jobs/{job_id}/replay", "expires": None}
