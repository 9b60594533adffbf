"""The probes of issue 11 that used to reach a 500: each now gets a 4xx naming the field and
the rule, and nothing is stored."""

from __future__ import annotations

import json

import pytest
from svc_helpers import bend_spec

from service.body import MAX_JSON_DEPTH, json_depth

JSON = {"content-type": "application/json"}


@pytest.fixture
def client(http_client):
    return http_client


def _nothing_stored(client):
    assert client.get("/jobs").json()["total"] == 0


@pytest.mark.parametrize("url", [
    "/jobs?offset=9223372036854775808",
    "/jobs?offset=9223372036854775807",
    "/cmrts?offset=9223372036854775808",
    "/cmrts?family=bend&duration=0.3&offset=9223372036854775808",
    "/jobs/x/generations?after=9223372036854775808",
])
def test_huge_integers_in_the_query(client, url):
    r = client.get(url)
    assert r.status_code == 422, r.text
    field = "after" if "after" in url else "offset"
    assert r.json()["detail"].startswith(f"{field}: ")
    assert "less than or equal to 1000000000" in r.json()["detail"]


def test_largest_offset_allowed(client):
    r = client.get("/jobs?offset=1000000000")
    assert r.status_code == 200 and r.json()["items"] == []


def _nested(depth: int, kind: str) -> bytes:
    if kind == "array":
        return b"[" * depth + b"]" * depth
    return b'{"a":' * depth + b"1" + b"}" * depth


@pytest.mark.parametrize("kind", ["array", "object"])
@pytest.mark.parametrize("depth", [990, 100_000])
@pytest.mark.parametrize("where", ["body", "spec", "bases"])
def test_deep_json_is_refused_before_parsing(client, kind, depth, where):
    inner = _nested(depth, kind)
    if where == "spec":
        body = b'{"spec": {"name": "x", "clip": ' + inner + b"}}"
    elif where == "bases":
        body = b'{"family": ' + inner + b"}"
    else:
        body = inner
    r = client.post("/bases" if where == "bases" else "/jobs", content=body, headers=JSON)
    assert r.status_code == 400, r.text
    assert r.json()["detail"] == (f"body: JSON nested deeper than {MAX_JSON_DEPTH} levels "
                                  "(arrays/objects) is refused")
    _nothing_stored(client)


def test_depth_limit_is_exact_and_ignores_strings(client):
    assert json_depth(_nested(MAX_JSON_DEPTH, "array")) == MAX_JSON_DEPTH
    assert json_depth(b'{"a": "[[[[[[[[\\"[[[[", "b": [1]}') == 2
    ok = client.post("/bases", content=b'{"family": "bend", "k": 2, "x": '
                     + _nested(MAX_JSON_DEPTH - 1, "array") + b"}", headers=JSON)
    assert ok.status_code == 422 and ok.json()["detail"].startswith("x: ")  # parsed, then rule
    # brackets inside a string are no nesting: the body is parsed and the spec's rule answers
    r = client.post("/jobs", json={"spec": {**bend_spec(), "name": "[" * 90}})
    assert r.status_code == 422 and "name: String should match pattern" in r.json()["detail"]


@pytest.mark.parametrize(("edit", "field"), [
    (lambda s: s["optimize"].update(threshold="1e999"), "optimize.threshold"),
    (lambda s: s.update(schedule=[{"scale": {"k_t": 2.0}, "end": "1e999"}]), "schedule.0.end"),
    (lambda s: s["clip"].update(duration="-1e999"), "clip.duration"),
])
def test_overflowing_numbers_are_refused(client, edit, field):
    spec = bend_spec()
    edit(spec)
    text = json.dumps({"spec": spec})
    text = text.replace('"1e999"', "1e999").replace('"-1e999"', "-1e999")
    r = client.post("/jobs", content=text.encode(), headers=JSON)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == (f"spec.{field}: must be a finite number "
                                  "(the value overflows a double)")
    _nothing_stored(client)


def test_overflowing_numbers_on_bases(client):
    r = client.post("/bases", content=b'{"family": "bend", "k": 1e999}', headers=JSON)
    assert r.status_code == 422 and r.json()["detail"].startswith("k: must be a finite")


@pytest.mark.parametrize("url", ["/jobs?family=a%00b", "/cmrts?family=bend&dur%00=1",
                                 "/jobs/a%00b", "/cmrts?family=x%00"])
def test_nul_in_path_or_query(client, url):
    r = client.get(url)
    assert r.status_code == 422, r.text
    assert "NUL character is not allowed" in r.json()["detail"]


def test_non_finite_tolerance(client):
    for v in ("inf", "nan", "1e999"):
        r = client.get(f"/cmrts?family=bend&duration=0.3&tolerance={v}")
        assert r.status_code == 422 and r.json()["detail"].startswith("tolerance: "), r.text
