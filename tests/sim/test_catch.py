"""The catch task (sim/tasks/catch.py, examples/catch.yaml) on real ODE clips: the throw
reaches the hands, the weld carries the ball's weight to the ground, a miss is penalised."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from sim.dynamics import GRAVITY
from sim.errors import SpecError
from sim.rollout import Rollout, fall_penalty
from sim.spec import load_spec, parse_spec
from sim.tasks.catch import BALL

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "catch.yaml"

pytestmark = pytest.mark.slow


def _spec(**task):
    data = yaml.safe_load(EXAMPLE.read_text())
    data["task"] = {**data["task"], **task}
    return parse_spec(data, source="catch")


def test_example_and_its_parameters():
    spec = load_spec(EXAMPLE)
    assert spec.task_type == "catch" and spec.task.ball.mass == 7.0
    assert (spec.clip.preparation, spec.clip.duration, spec.clip.decay) == (1.0, 0.3, 1.7)
    assert spec.task_parameters() == {"duration": 0.3, "mass": 7.0}
    assert _spec(ball={"mass": 1.0}).task_parameters()["mass"] == 1.0


@pytest.mark.parametrize(("task", "field", "rule"), [
    ({"hold": {"wrist": 10.0}}, "task.hold", "unknown joint 'wrist'"),
    ({"throw": {"flight": 1.5}}, "task.throw.flight", "released before the clip starts"),
    ({"throw": {"arrival": 4.0}}, "task.throw.arrival", "after the end of the clip"),
    ({"ball": {"mass": 0.0}}, "task.ball.mass", "must be from 0.05 to 50 kg, got 0.0"),
    ({"ball": {"mass": "7"}}, "task.ball.mass", "valid number"),
    ({"ball": {"weight": 7.0}}, "task.ball.weight", "Extra inputs"),
])
def test_bad_catch_specs(task, field, rule):
    with pytest.raises(SpecError) as info:
        _spec(**task)
    assert field in str(info.value) and rule in str(info.value)


@pytest.fixture(scope="module")
def light_catch():
    """A 3 kg ball: the reactive controller alone stands after catching it."""
    sim = Rollout(_spec(ball={"mass": 3.0}))
    try:
        yield sim, sim.run(traces=True)
    finally:
        sim.close()


def test_ball_reaches_the_hands_at_the_task_time_and_is_held(light_catch):
    sim, ev = light_catch
    task = sim.task
    assert task.release == pytest.approx(0.3)
    # Welded when within 2 cm of touching: ~0.17 m before the centres meet, at ~3.6 m/s.
    assert 0.9 < task.caught_at < 1.0
    assert ev.task_success is True and ev.task_penalty == 0.0
    assert not ev.fell and ev.fall_direction is None
    assert sim.physics.attached(BALL)
    # The ball stayed with the hands: its last pose is near the hands' geoms.
    bx, by, _ = sim.physics.prop(BALL).pose()
    hx, hy, _ = sim.physics.geoms[sim.character.hands[0]].getPosition()
    assert np.hypot(bx - hx, by - hy) < 0.11 + 0.05 + 0.02 + 1e-3


def test_ground_reaction_carries_the_ball_after_the_catch(light_catch):
    """Once settled (the last 0.5 s), the feet's normal force is (m + m_ball) g within 1 %;
    before the throw it is m g."""
    sim, ev = light_catch
    tr = ev.traces
    m = sim.character.total_mass
    before = tr.normal[(tr.t > 0.2) & (tr.t < 0.8)]
    settled = tr.normal[tr.t > 2.5]
    assert np.mean(before) == pytest.approx(m * GRAVITY, rel=1e-3)
    print(f"settled normal force {np.mean(settled):.2f} N, (m + m_ball) g "
          f"{(m + 3.0) * GRAVITY:.2f} N, std {np.std(settled):.2f} N")
    assert np.mean(settled) == pytest.approx((m + 3.0) * GRAVITY, rel=0.01)
    assert np.std(settled) < 0.01 * (m + 3.0) * GRAVITY


def test_frames_include_the_ball(light_catch):
    sim, ev = light_catch
    f = ev.frames
    j = f.names.index(BALL)
    assert j == sim.character.n_bodies
    # Before the release it waits at the release point, 2 m ahead of the hands.
    x0 = f.poses[0][j][0]
    assert x0 == pytest.approx(f.poses[20][j][0])  # t = 0.2 s: not released yet
    assert f.poses[60][j][0] < x0 - 0.5  # t = 0.6 s: in flight toward the hands


def test_seven_kg_ball_without_anticipation_falls_forward():
    """The paper's top row of Figure 10."""
    ev = Rollout(load_spec(EXAMPLE)).run()
    assert ev.task_success is True  # caught, then
    assert ev.fell and ev.fall_direction == "forward"


def test_a_ball_not_caught_is_penalised_above_every_catch():
    """A CMRT leaning 12 cm forward carries the hands away from where the ball was aimed (it
    flies past) and falls just after: no catch, the objective is the fall penalty plus twice
    the penalty unit."""
    spec = load_spec(EXAMPLE)
    sim = Rollout(spec)
    try:
        ev = sim.run(lambda t: 0.12 if t > 0.1 else 0.0)
        unit = np.sqrt(sim.steps) * sim.support_length
        assert ev.fell and sim.task.caught_at is None
        assert ev.task_success is False and ev.task_penalty == pytest.approx(2.0 * unit)
        assert ev.objective == pytest.approx(
            fall_penalty(ev.fall_time, spec.clip.length, sim.steps, sim.support_length)
            + 2.0 * unit)
        assert ev.objective > 2.0 * unit  # above any caught clip, fallen or not
        assert not sim.physics.attached(BALL)
    finally:
        sim.close()
