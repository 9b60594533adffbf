"""A user's character on the running topology (Celery workers on a host of their own, Redis,
PostgreSQL): the fast bend on examples/my_character.yaml, stored by name with POST /characters
and sent by name, optimises on the workers to the same objective, by `repr`, as `cmrt
optimize` on this machine, and the job holds the definition (the workers read no file)."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from conftest import submit, wait_job

from cli.main import main
from cmrt.canonical import document_hash

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
#: Two generations of four: the job machinery whole, ~2 s of the workers' CPU.
SHORT = {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0, "sigma0": 0.05}


def test_a_users_character_gives_the_command_lines_objective_on_celery(api, tmp_path):
    definition = yaml.safe_load((EXAMPLES / "my_character.yaml").read_text())
    r = api.post("/characters", json={"name": "it_mine", "definition": definition})
    assert r.status_code == 201, r.text
    spec = yaml.safe_load((EXAMPLES / "fast_bend_my_character.yaml").read_text())
    spec["optimize"] = SHORT
    local = dict(spec, character={"file": str(EXAMPLES / "my_character.yaml"),
                                  "model": "it_mine"})
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(local))
    out = tmp_path / "result.json"
    assert main(["optimize", str(tmp_path / "spec.yaml"), "--workers", "1", "--seed", "5",
                 "--out", str(out)]) == 0
    cli = json.loads(out.read_text())

    job_id = submit(api, dict(spec, character={"model": "it_mine"}), seed=5)
    job = wait_job(api, job_id, 180)
    assert job["status"] == "stopped", job
    assert job["spec"]["character"]["definition"] == definition
    assert repr(job["best_objective"]) == repr(cli["objective"])
    best = api.get(f"/jobs/{job_id}/best").json()
    assert repr(best["params"]) == repr(cli["params"])
    # its library CMRT tells the character by the definition's hash (the spec holds it whole)
    entry = api.get(f"/cmrts/{job['cmrt_id']}").json()
    assert entry["character"] == {"model": "it_mine", "height": 1.7928, "mass": 74.97,
                                  "definition_hash": document_hash(definition)}
    # the inline definition is the same job: its spec document is the stored one
    again = api.post("/jobs", json={"spec": dict(spec, character={
        "model": "it_mine", "definition": definition}), "seed": 5, "start": "cold"})
    assert api.get(f"/jobs/{again.json()['id']}").json()["spec"] == job["spec"]
    api.post(f"/jobs/{again.json()['id']}/cancel")
