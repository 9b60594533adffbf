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


def test_repeated_bench_reports_the_totals_and_each_round() -> None:
    """`repeat` rounds: the old keys hold the rates over every round (CPU over simulated
    seconds), and each round's ratios are listed for their range."""
    from sim.bench import run_bench

    r = run_bench(seconds=0.05, repeat=2)
    assert r["repeat"] == 2 and r["replay_reproduced_clip"]
    assert len(r["controller_over_raw_ode_runs"]) == 2
    assert len(r["controller_over_replay_ode_runs"]) == 2
    assert r["controller_over_raw_ode"] == r["controller_cpu_per_sim_second"] / r[
        "raw_ode_cpu_per_sim_second"]
    assert min(r["controller_over_replay_ode_runs"]) > 0.0
