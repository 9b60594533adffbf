"""POST /simulations with a non-default controller block: the spec reaches the API's
simulation pool unchanged (its objective is the direct rollout's, bit for bit), and a bad
controller block is a 422 naming the field."""

from __future__ import annotations

import pytest
from svc_helpers import QUIET

from sim import evaluate, parse_spec


@pytest.mark.parametrize("controller", [{"type": "pd_world", "root": "person"},
                                        {"type": "pd_parent", "k1": 150.0}])
def test_pd_clip_is_the_direct_rollout(client, controller):
    spec = {**QUIET, "controller": controller}
    r = client.post("/simulations", json={"spec": spec, "traces": False})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["status"] == "done" and out["fell"] is False
    assert out["objective"] == evaluate(parse_spec(spec)).objective


# The API names the field as the spec's author wrote it, as sim.parse_spec (the CLI) does:
# pydantic's union tag (spec.controller.pd_world.k2) is not in the path.
@pytest.mark.parametrize(("controller", "needle"), [
    ({"type": "pd"}, "spec.controller: must be a mapping whose `type` is "
                     "one of momentum, pd_parent, pd_world"),
    ({"type": "pd_world", "k2": -1.0}, "spec.controller.k2: must be from 0.001 to 1000"),
    ({"type": "momentum", "stepping": True, "response_delay": -1},
     "spec.controller.response_delay: must be from 0 to 1 s, got -1"),
])
def test_bad_controller_block_is_422(client, controller, needle):
    r = client.post("/simulations", json={"spec": {**QUIET, "controller": controller}})
    assert r.status_code == 422, r.text
    assert needle in r.json()["detail"], r.json()["detail"]


def test_task_field_error_names_the_field_without_its_union_tag(client):
    spec = {**QUIET, "task": {"type": "push", "force": 1e9}}
    r = client.post("/simulations", json={"spec": spec})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("spec.task.force: "), detail

