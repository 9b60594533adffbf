"""The bench's open-loop replay steps the clip's own world (sim.bench)."""

from __future__ import annotations

from pathlib import Path

from sim import load_spec
from sim.bench import replay_ode_cpu_per_second
from sim.rollout import Rollout

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_replay_reproduces_the_clip_with_its_throw_and_catch() -> None:
    """Replaying the controller's torques and contact points with the task's events (the
    throw, the weld of the catch) ends with every body and the ball where the clip left them,
    bit for bit: the replay is the same world, so the ratio to it is the controller's cost."""
    sim = Rollout(load_spec(EXAMPLES / "catch.yaml"))
    ev = sim.run()
    rate, seconds, same = replay_ode_cpu_per_second(sim)
    assert same
    assert seconds == ev.sim_seconds
    assert rate > 0.0
    assert sim.task.caught_at is not None  # the replay went through the catch
    sim.close()
