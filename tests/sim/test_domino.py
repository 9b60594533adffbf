"""The domino task: spec rules naming the field, the block at rest, the push's contact and
toppling, the library key, determinism."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from sim.dynamics import GRAVITY
from sim.errors import SpecError
from sim.physics import PROP_CHARACTER
from sim.rollout import Rollout
from sim.spec import load_spec, parse_spec
from sim.tasks.domino import BLOCK, DominoTask

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "domino.yaml"


def _data(**task) -> dict:
    data = yaml.safe_load(EXAMPLE.read_text())
    data["task"].update(task)
    return data


@pytest.mark.parametrize(("task", "message"), [
    ({"mass": -1.0}, r"task\.mass: must be from 1 to 1000 kg, got -1\.0"),
    ({"width": 2.0, "height": 1.0}, r"task: .*width must be below height"),
    ({"ready": {"wrist": 10.0}}, r"task\.ready: unknown joint 'wrist'"),
    ({"push": {"shoulder_r": 200.0}},
     r"task\.push\.shoulder_r: must be from -180 to 180 degrees, got 200\.0"),
    ({"ready_time": 1.5}, r"task\.ready_time: 1\.5 s ends after the preparation"),
    ({"colour": "red"}, r"task\.colour: Extra inputs are not permitted"),
])
def test_bad_fields_are_named(task, message):
    with pytest.raises(SpecError, match=message):
        parse_spec(_data(**task))


def test_example_parses_with_mass_as_library_key():
    spec = load_spec(EXAMPLE)
    assert spec.task_type == "domino"
    assert spec.task_parameters() == {"duration": 0.35, "mass": 140.0}
    assert (spec.clip.preparation, spec.clip.duration, spec.clip.decay) == (1.0, 0.35, 1.65)
    assert spec.optimize.threshold == 0.6


def test_block_at_rest_stays_put():
    """The block out of the hands' reach (1.5 m away, the push in the air): it keeps its pose
    to 0.1 mm / 0.1 mrad, no hand touches it, and its ground contacts carry its weight to 1 %."""
    data = _data(distance=1.5)
    rollout = Rollout(parse_spec(data))
    block = rollout.physics.prop(BLOCK)
    x0, y0, a0 = block.definition.position + (block.definition.angle,)
    task, after = rollout.task, rollout.task.after_step
    weight, touches = [], []

    def watch(phys, t):
        after(phys, t)
        touches.extend(c for c in phys.contact_list() if c.kind == PROP_CHARACTER)
        weight.append(sum(c.force[1] for c in phys.contact_list()
                          if c.a == BLOCK and c.b is None))

    task.after_step = watch
    ev = rollout.run()
    x, y, a = block.pose()
    rollout.close()
    assert not ev.fell and ev.task_success is False and not touches
    assert abs(x - x0) < 1e-4 and abs(y - y0) < 1e-3 and abs(a - a0) < 1e-4
    assert np.mean(weight[-100:]) == pytest.approx(data["task"]["mass"] * GRAVITY, rel=0.01)


def _push(mass: float) -> tuple[object, DominoTask, float]:
    """Run the example with the block's mass changed; (evaluation, task, largest hand force)."""
    rollout = Rollout(parse_spec(_data(mass=mass)))
    task = rollout.task
    seen = [0.0]
    after = task.after_step

    def watch(phys, t):
        after(phys, t)
        f = sum(c.force[0] for c in phys.contact_list() if c.kind == PROP_CHARACTER)
        seen[0] = max(seen[0], f)

    task.after_step = watch
    ev = rollout.run()
    rollout.close()
    return ev, task, seen[0]


def test_push_contacts_and_topples_a_light_block():
    ev, task, force = _push(30.0)
    assert force > 10.0  # the hands pushed the block (N, on the block, forward)
    assert ev.task_success is True and task.max_tilt > task.tip_angle
    assert ev.task_penalty == 0.0


def test_heavy_block_without_anticipation():
    """The paper's case without a CMRT: the 140 kg block is not toppled and the character
    falls backward (the reaction of the push)."""
    ev, task, force = _push(140.0)
    assert force > 10.0
    assert ev.fell and ev.fall_direction == "backward"
    assert ev.task_success is False and ev.task_penalty > 0.0
    assert task.max_tilt < task.tip_angle


def test_deterministic():
    spec = load_spec(EXAMPLE)
    a, b = Rollout(spec), Rollout(spec)
    ea, eb = a.run(), b.run()
    ea2 = a.run()
    for other in (eb, ea2):
        assert other.objective == ea.objective
        assert other.task_success == ea.task_success
    assert math.isfinite(ea.objective) and np.isfinite(ea.error_norm)
    a.close()
    b.close()
