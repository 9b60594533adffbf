"""The optimiser's objective with a non-default controller block (the spec as the workers
receive it)."""

from __future__ import annotations

import pickle
from pathlib import Path

import yaml

from optim.objective import SimObjective
from optim.spline import decode, flat_params
from sim.rollout import Rollout
from sim.spec import parse_spec

EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"


def test_the_optimiser_objective_sees_the_pd_spec_unchanged():
    """optim's objective carries the spec as JSON (what the workers receive): the pd_world
    block survives it, and its evaluation is the rollout's, bit for bit."""
    d = yaml.safe_load((EXAMPLES_DIR / "slow_bend.yaml").read_text())
    d["controller"] = {"type": "pd_world", "k1": 120.0, "root": "person"}
    spec = parse_spec(d)
    objective = pickle.loads(pickle.dumps(SimObjective(spec)))
    assert objective.spec == spec and objective.spec.controller.root == "person"
    params = flat_params(spec)
    sim = Rollout(spec)
    try:
        direct = sim.run(decode(spec, params))
    finally:
        sim.close()
    assert objective(params).objective == direct.objective
