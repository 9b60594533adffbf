"""`tire_hit`: the fore-paws (the character's `hands`) strike a bouncing tire (paper 6.1.7;
the tire, its launch and the scoring: `sim.tasks.tire`)."""

from __future__ import annotations

from typing import Any, Literal

from sim.tasks.base import Task
from sim.tasks.tire import TireConfig, TireTask


class TireHitConfig(TireConfig):
    """`task: {type: tire_hit, launch: {...}, tire?: {...}, motions?: [...]}`: the paws strike
    the tire."""

    type: Literal["tire_hit"] = "tire_hit"
    NEEDS = ("hands",)

    def build(self, spec: Any, character: Any) -> Task:
        return TireTask(spec, character, hit=True)
