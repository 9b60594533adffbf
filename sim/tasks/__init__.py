"""The registry of task types, resolved by the spec's `task.type`.

Each entry is one module's `TaskConfig` subclass (see `sim.tasks.base` for the contract). A new
task type is a module plus one line here.
"""

from __future__ import annotations

from sim.tasks.base import Task, TaskConfig
from sim.tasks.catch import CatchConfig
from sim.tasks.domino import DominoConfig
from sim.tasks.motion import MotionConfig
from sim.tasks.pose_change import PoseChangeConfig
from sim.tasks.pull import PullConfig
from sim.tasks.punch import PunchConfig
from sim.tasks.push import PushConfig
from sim.tasks.quiet_stance import QuietStanceConfig
from sim.tasks.sequence import SequenceConfig
from sim.tasks.tire_dodge import TireDodgeConfig
from sim.tasks.tire_hit import TireHitConfig

TASK_TYPES: dict[str, type[TaskConfig]] = {
    "quiet_stance": QuietStanceConfig,
    "push": PushConfig,
    "pose_change": PoseChangeConfig,
    "sequence": SequenceConfig,
    "motion": MotionConfig,
    "catch": CatchConfig,
    "punch": PunchConfig,
    "domino": DominoConfig,
    "pull": PullConfig,
    "tire_hit": TireHitConfig,
    "tire_dodge": TireDodgeConfig,
}

__all__ = ["TASK_TYPES", "Task", "TaskConfig"]
