"""`quiet_stance`: the reactive controller alone holds the standing pose; no event."""

from __future__ import annotations

from typing import Any, Literal

from sim.tasks.base import Task, TaskConfig


class QuietStanceConfig(TaskConfig):
    """`task: {type: quiet_stance}`."""

    type: Literal["quiet_stance"] = "quiet_stance"

    def build(self, spec: Any, character: Any) -> Task:
        return Task(spec, character)
