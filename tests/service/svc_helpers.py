"""Helpers of the service unit tests."""

from __future__ import annotations


def bend_spec(name: str = "bend_a", duration: float = 0.3, **optimize) -> dict:
    opt = {"popsize": 4, "max_evaluations": 12, "min_evaluations": 0}
    opt.update(optimize)
    return {
        "name": name,
        "family": "bend",
        "clip": {"preparation": 0.3, "duration": duration, "decay": 0.2},
        "task": {"type": "pose_change", "target": {"waist": -30}},
        "optimize": opt,
    }
