"""`sequence`: several pose changes in a row (paper Figure 4)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from sim.specbase import StrictModel, quantity
from sim.tasks.base import (
    MIN_MOTION_SECONDS,
    ClipTime,
    Pose,
    Task,
    TaskConfig,
    check_pose,
    pose_offsets,
)
from sim.trajectory import MotionDef

MAX_MOTIONS = 32


class SequenceMotion(StrictModel):
    """A pose change: ease-in-ease-out from the current target to `target` over `duration`.

    `target` maps hinge names to angles in degrees relative to the standing pose; joints not
    named keep their previous target. `start` is seconds from the clip's start.
    `cmrt` optionally names a result file whose CMRT is superposed for this motion.
    """

    target: Pose
    start: ClipTime
    duration: quantity(MIN_MOTION_SECONDS, 10.0, "s")
    cmrt: Annotated[str, Field(min_length=1, max_length=1000)] | None = None


class SequenceConfig(TaskConfig):
    """`task: {type: sequence, motions: [{start, duration, target, cmrt?}, ...]}`."""

    type: Literal["sequence"] = "sequence"
    motions: Annotated[list[SequenceMotion], Field(min_length=1, max_length=MAX_MOTIONS)]

    def check(self, spec: Any, character: Any) -> None:
        for i, m in enumerate(self.motions):
            check_pose(m.target, character, f"task.motions.{i}.target")
            if m.start + m.duration > spec.clip.length + 1e-9:
                raise ValueError(f"task.motions.{i}: start + duration exceeds the clip length")

    def build(self, spec: Any, character: Any) -> Task:
        return SequenceTask(spec, character)


class SequenceTask(Task):
    @property
    def motions(self) -> list[MotionDef]:
        return [(m.start, m.duration, pose_offsets(m.target, self.character))
                for m in self.spec.task.motions]
