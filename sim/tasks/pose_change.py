"""`pose_change`: one pose change over the clip's task window."""

from __future__ import annotations

from typing import Any, Literal

from sim.tasks.base import Pose, Task, TaskConfig, check_pose, pose_offsets
from sim.trajectory import MotionDef


class PoseChangeConfig(TaskConfig):
    """`task: {type: pose_change, target: {joint: degrees, ...}}`: ease-in-ease-out from the
    standing pose to `target` (degrees relative to the standing pose; joints not named keep
    theirs) over the task window."""

    type: Literal["pose_change"] = "pose_change"
    target: Pose

    def check(self, spec: Any, character: Any) -> None:
        check_pose(self.target, character, "task.target")

    def build(self, spec: Any, character: Any) -> Task:
        return PoseChangeTask(spec, character)


class PoseChangeTask(Task):
    @property
    def motions(self) -> list[MotionDef]:
        clip = self.spec.clip
        return [(clip.task_start, clip.duration, pose_offsets(self.spec.task.target,
                                                              self.character))]
