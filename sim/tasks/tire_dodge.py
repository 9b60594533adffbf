"""`tire_dodge`: the character lowers itself to let a bouncing tire pass (paper 6.1.8; the
tire, its launch and the scoring: `sim.tasks.tire`)."""

from __future__ import annotations

from typing import Any, Literal

from sim.tasks.base import Task
from sim.tasks.tire import TireConfig, TireTask


class TireDodgeConfig(TireConfig):
    """`task: {type: tire_dodge, launch: {...}, tire?: {...}, motions?: [...]}`: the tire must
    pass without touching the character."""

    type: Literal["tire_dodge"] = "tire_dodge"

    def build(self, spec: Any, character: Any) -> Task:
        return TireTask(spec, character, hit=False)
