"""The spec's `controller` block: a discriminated union on `type` (momentum when the block is
left out), a block without its type refused saying what to send, errors naming the field."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from sim.controllers import MomentumController
from sim.controllers.config import MomentumConfig
from sim.controllers.registry import CONTROLLER_TYPES
from sim.errors import SpecError
from sim.spec import parse_spec

EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"


def _bend(controller=None) -> dict:
    d = yaml.safe_load((EXAMPLES_DIR / "slow_bend.yaml").read_text())
    if controller is not None:
        d["controller"] = controller
    return d


def test_registry_holds_the_default_type():
    assert CONTROLLER_TYPES["momentum"] is MomentumConfig


def test_a_block_without_its_type_is_refused_saying_what_to_send():
    for flat in ({"k_l": 30.0, "d_t": 25.0}, {}):
        with pytest.raises(SpecError, match=r"controller\.type: required: send "
                                            r"\{type: momentum, \.\.\.\}"):
            parse_spec(_bend(flat))
    tagged = parse_spec(_bend({"type": "momentum", "k_l": 30.0, "d_t": 25.0}))
    assert tagged.controller.overrides() == {"k_l": 30.0, "d_t": 25.0}
    # The dump is the tagged form with only the set gains, and reads back to the same spec.
    dumped = tagged.model_dump(mode="json")["controller"]
    assert dumped == {"type": "momentum", "stepping": False, "k_l": 30.0, "d_t": 25.0}
    assert parse_spec(tagged.model_dump(mode="json")) == tagged


def test_no_controller_is_the_default_momentum():
    absent = parse_spec(_bend())
    assert absent.controller.type == "momentum" and absent.controller.overrides() == {}


@pytest.mark.parametrize(("block", "field", "rule"), [
    ({"type": "walk"}, "controller.type", "unknown controller type 'walk'"),
    ({"type": 3}, "controller.type", "one of momentum"),
    ([1.0], "controller.type", "must be a mapping"),
    ({"type": "momentum", "kl": 20.0}, "controller", "unknown gain 'kl'"),
    ({"type": "momentum", "k_l": -1.0}, "controller.k_l", "must be from 0.001 to 10000 s^-2"),
    ({"type": "momentum", "k_l": "20"}, "controller.k_l", "valid number"),
    ({"type": "momentum", "stepping": 1}, "controller.stepping", "valid boolean"),
    ({"type": "momentum", "response_delay": 0.2}, "controller",
     "response_delay: applies only with stepping: true"),
    ({"type": "momentum", "stepping": True, "response_delay": -0.1},
     "controller.response_delay", "must be from 0 to 1 s, got -0.1"),
    ({"type": "momentum", "max_steps": 2}, "controller",
     "max_steps: applies only with stepping: true"),
    ({"type": "momentum", "stepping": True, "max_steps": 0}, "controller.max_steps",
     "must be from 1 to 20 steps, got 0"),
    ({"type": "momentum", "stepping": True, "max_steps": 2.5}, "controller.max_steps",
     "valid integer"),
    ({"type": "momentum", "stepping": True, "capture_margin": -0.01},
     "controller.capture_margin", "must be from 0 to 0.3 m, got -0.01"),
    ({"type": "momentum", "stepping": True, "step_duration": 0.05},
     "controller.step_duration", "must be from 0.1 to 1 s, got 0.05"),
    ({"type": "momentum", "stepping": True, "clearance": 0.5},
     "controller.clearance", "must be from 0.01 to 0.3 m, got 0.5"),
    ({"type": "momentum", "stepping": True, "max_step_fraction": 1.5},
     "controller.max_step_fraction", "must be from 0.1 to 1 (of the leg length), got 1.5"),
    ({"type": "momentum", "cop_box": 0.5}, "controller.cop_box", "below half the support length"),
    ({"type": "momentum", "feet_fixed": {"d_l": 20.0}}, "controller",
     "feet_fixed: applies only with stepping: true"),
    ({"type": "momentum", "stepping": True, "feet_fixed": {"dl": 20.0}}, "controller",
     "feet_fixed: unknown gain 'dl'"),
    ({"type": "momentum", "stepping": True, "feet_fixed": {"cop_box": 1.0}},
     "controller.feet_fixed.cop_box", "below half the support length"),
])
def test_bad_controller_block_names_field_and_rule(block, field, rule):
    with pytest.raises(SpecError) as info:
        parse_spec(_bend(block), source="bad.yaml")
    msg = str(info.value)
    assert msg.startswith(f"bad.yaml: {field}: "), msg
    assert rule in msg, msg


def test_rollout_builds_the_momentum_controller_from_the_block():
    from sim.rollout import Rollout

    sim = Rollout(parse_spec(_bend({"type": "momentum", "k_l": 30.0})))
    try:
        assert isinstance(sim.controller, MomentumController)
        assert sim.controller.schedule.base.k_l == 30.0
        assert sim.controller.schedule.base.d_l == 7.0  # the default stays
    finally:
        sim.close()


def test_stepping_settings_reach_the_step_controller():
    """Every stepping setting of the block is the step controller's; an absent one keeps its
    default, and a block that sets none dumps as before."""
    from sim.controllers.stepping import SteppingParams
    from sim.rollout import Rollout

    block = {"type": "momentum", "stepping": True, "response_delay": 0.2, "capture_margin": 0.01,
             "step_duration": 0.35, "clearance": 0.06, "max_step_fraction": 0.6, "max_steps": 3}
    spec = parse_spec(_bend(block))
    assert spec.controller.model_dump() == block
    sim = Rollout(spec)
    try:
        got = sim.controller.params
    finally:
        sim.close()
    want = {k: v for k, v in block.items() if k not in ("type", "stepping")}
    assert {k: getattr(got, k) for k in want} == want
    assert got.feet_fixed_gains == SteppingParams().feet_fixed_gains
    plain = parse_spec(_bend({"type": "momentum", "stepping": True}))
    assert plain.controller.model_dump() == {"type": "momentum", "stepping": True}
