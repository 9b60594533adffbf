"""A user's character through the service: a spec's inline `definition` is stored with the job
(its hash covers it); a bad definition is a 422 naming the field, and nothing is stored."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from sim.spec import load_spec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
MINE = yaml.safe_load((EXAMPLES / "my_character.yaml").read_text())


@pytest.fixture
def client(http_client):
    return http_client


def _bend(character: dict) -> dict:
    spec = yaml.safe_load((EXAMPLES / "fast_bend.yaml").read_text())
    return {**spec, "character": copy.deepcopy(character)}


def test_a_job_holds_the_definition_itself(client):
    r = client.post("/jobs", json={"spec": _bend({"definition": MINE, "model": "mine"})})
    assert r.status_code == 202, r.text
    job = client.get(f"/jobs/{r.json()['id']}").json()
    assert job["spec"]["character"]["definition"] == MINE
    assert job["spec"]["character"]["model"] == "mine"
    # a spec without a definition is stored as it always was
    r = client.post("/jobs", json={"spec": _bend({"model": "humanoid"})})
    job = client.get(f"/jobs/{r.json()['id']}").json()
    assert set(job["spec"]["character"]) == {"model", "height", "mass"}
    assert load_spec(EXAMPLES / "fast_bend.yaml").model_dump(mode="json") == job["spec"]


def _mutations():
    def seg(d, i):
        return d["segments"][i]
    return [
        (lambda d: seg(d, 2).update(mass=1e-9), "segments[2].mass: must be at least 0.1 kg"),
        (lambda d: seg(d, 1).update(mass=1e6), "segments[1].inertia: must be from"),
        (lambda d: d.update(segments=d["segments"] * 77), "segments: at most 48 segments"),
        (lambda d: seg(d, 3).update(parent="shank_r"), "segments[3].parent: 'shank_r' must "
                                                       "name a segment listed before"),
        (lambda d: seg(d, 12).update(inertia=1e3), "segments[12].inertia: must be from"),
        (lambda d: seg(d, 1)["joint"].update(limits=[30, -30]),
         "segments[1].joint.limits: must be [lo, hi] degrees, lo < hi"),
        (lambda d: seg(d, 5)["foot"].update(toe=[0.176, 0.2]),
         "segments[5].foot.toe: must be on the ground"),
    ]


def test_bad_definitions_are_refused_naming_the_field_and_nothing_is_stored(client):
    for mutate, message in _mutations():
        d = copy.deepcopy(MINE)
        mutate(d)
        r = client.post("/jobs", json={"spec": _bend({"definition": d})})
        assert r.status_code == 422, (message, r.text)
        assert r.json()["detail"].startswith(f"spec: character.definition: {message}"), \
            r.json()["detail"]
    # NaN cannot be sent as JSON; a file name is refused (the service reads no file)
    r = client.post("/jobs", json={"spec": _bend({"file": "my_character.yaml"})})
    assert r.status_code == 422 and r.json()["detail"].startswith(
        "spec: character: file: a character file is read by the command line")
    handless = copy.deepcopy(MINE)
    del handless["hands"]
    catch = yaml.safe_load((EXAMPLES / "catch.yaml").read_text())
    r = client.post("/jobs", json={"spec": {**catch, "character": {"definition": handless}}})
    assert r.status_code == 422
    assert "task.type: a catch task needs a character with hands" in r.json()["detail"]
    assert "character.definition.hands" in r.json()["detail"]
    assert client.get("/jobs").json()["total"] == 0


# ---- /characters --------------------------------------------------------------------------
def test_add_list_and_show_stored_and_shipped_characters(client):
    r = client.post("/characters", json={"name": "mine", "definition": MINE})
    assert r.status_code == 201, r.text
    out = r.json()
    assert r.headers["location"] == out["url"] and out["url"].endswith("/characters/mine")
    assert out["source"] == "stored" and out["definition"] == MINE
    assert out["summary"]["mass"] == pytest.approx(74.97)
    assert out["summary"]["hands"] == ["hand_r", "hand_l"] and out["summary"]["torso"] == "trunk"
    page = client.get("/characters").json()
    assert [c["name"] for c in page["items"]] == ["mine"] and page["total"] == 1
    assert page["items"][0]["definition"] is None  # the list holds summaries
    assert {"humanoid", "lion", "sumo"} <= set(page["shipped"])
    assert client.get("/characters/mine").json()["definition"] == MINE
    shipped = client.get("/characters/humanoid").json()
    assert shipped["source"] == "shipped" and shipped["summary"]["segments"] == 13
    assert client.get("/characters/nobody").status_code == 404


def test_taken_names_are_409_and_bad_definitions_422_storing_nothing(client):
    assert client.post("/characters", json={"name": "mine", "definition": MINE}
                       ).status_code == 201
    r = client.post("/characters", json={"name": "mine", "definition": MINE})
    assert r.status_code == 409 and r.json()["detail"] == "name: a character named 'mine' exists"
    r = client.post("/characters", json={"name": "humanoid", "definition": MINE})
    assert r.status_code == 409 and "'humanoid' is a shipped character" in r.json()["detail"]
    for mutate, message in _mutations():
        d = copy.deepcopy(MINE)
        mutate(d)
        r = client.post("/characters", json={"name": "bad", "definition": d})
        assert r.status_code == 422, (message, r.text)
        assert r.json()["detail"].startswith(f"definition: {message}"), r.json()["detail"]
    for body, field in (({"name": "Bad Name", "definition": MINE}, "name"),
                        ({"name": "x", "definition": [1]}, "definition"),
                        ({"name": "x"}, "definition")):
        r = client.post("/characters", json=body)
        assert r.status_code == 422 and r.json()["detail"].startswith(f"{field}: "), r.text
    assert client.get("/characters").json()["total"] == 1


def test_a_spec_naming_a_stored_character_gets_its_definition(client):
    client.post("/characters", json={"name": "mine", "definition": MINE})
    r = client.post("/jobs", json={"spec": _bend({"model": "mine", "height": 1.8})})
    assert r.status_code == 202, r.text
    spec = client.get(f"/jobs/{r.json()['id']}").json()["spec"]
    assert spec["character"] == {"model": "mine", "definition": MINE, "height": 1.8,
                                 "mass": 74.97}
    # the stored job is the inline spec: same document
    inline = client.post("/jobs", json={"spec": _bend({"model": "mine", "height": 1.8,
                                                       "definition": MINE})})
    assert client.get(f"/jobs/{inline.json()['id']}").json()["spec"] == spec
    r = client.post("/jobs", json={"spec": _bend({"model": "nobody"})})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("spec: character.model: unknown character 'nobody'")


def test_simulations_and_families_take_a_stored_character_by_name(client):
    from svc_helpers import QUIET

    client.post("/characters", json={"name": "mine", "definition": MINE})
    r = client.post("/simulations", json={"spec": {**QUIET, "character": {"model": "mine"}}})
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "done" and not r.json()["fell"]
    fam = {"spec": {**_bend({"model": "mine"}), "optimize": {"max_evaluations": 4,
                                                             "min_evaluations": 0,
                                                             "popsize": 4}},
           "param": "clip.duration", "values": [0.3, 0.4, 0.5], "k": 2}
    r = client.post("/families", json=fam)
    assert r.status_code == 202, r.text
    stored = client.get(f"/families/{r.json()['id']}").json()["spec"]["spec"]
    assert stored["character"]["definition"] == MINE
