"""One seed default: the command line, a job without a seed, a family and a refinement all
run with `cmrt.defaults.DEFAULT_SEED`, and a job's record says which seed it ran with."""

from __future__ import annotations

from svc_helpers import bend_spec

from cli.main import build_parser
from cmrt.defaults import DEFAULT_SEED
from optim.family.spec import FamilySpec
from service.schemas import RefineRequest


def test_every_door_has_the_same_seed_default(http_client):
    args = build_parser().parse_args(["optimize", "examples/fast_bend.yaml"])
    assert args.seed == DEFAULT_SEED
    fam = build_parser().parse_args(["family", "run", "examples/fast_bend.yaml", "--param",
                                     "clip.duration", "--values", "0.3", "0.4", "--out", "f.json"])
    assert fam.seed == DEFAULT_SEED
    assert FamilySpec.model_fields["seed"].default == DEFAULT_SEED
    assert RefineRequest.model_fields["seed"].default == DEFAULT_SEED

    r = http_client.post("/jobs", json={"spec": bend_spec()})
    assert r.status_code == 202, r.text
    job = http_client.get(r.json()["url"]).json()
    assert job["seed"] == DEFAULT_SEED
