"""Compatibility names for callers written before the reshape: `Simulator` is
`sim.rollout.Rollout`; `evaluate`, `fall_penalty` and `standing_state` live in `sim.rollout`."""

from sim.rollout import Rollout, evaluate, fall_penalty, standing_state

Simulator = Rollout

__all__ = ["Rollout", "Simulator", "evaluate", "fall_penalty", "standing_state"]
