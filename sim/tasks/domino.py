"""`domino`: a tall heavy block standing in front of the character, toppled by a two-handed push
(paper 6.1.5, Figure 12: a 140 kg block).

The block is a box prop resting on the ground with its near face `distance` m in front of the
ankles (x = 0). The push is a reference pose change of the arms, nothing else: in the
preparation window the arms ease from the standing pose to `ready` (hands in front of the
chest, elbows bent), and in the task window they extend to `push`. The momentum controller
tracks that motion; where the hands meet the block, ODE's contacts between the hand geoms and
the block push it, and the block's reaction reaches the character only through those contacts
(the controller does not model the block). A push that tilts the block past its tipping angle
atan(width / height) (its centre of mass beyond the far bottom edge) has toppled it.

Success (`Evaluation.task_success`): the block tilted forward past its tipping angle at the
end of the clip. A clip that ends without that gets a penalty of (1/2 + progress gap / 2) x the
objective's fall unit F0 (progress = the block's largest forward tilt over the tipping angle,
capped at 1), so a candidate that stands but leaves the block up ranks below every candidate
that stands and topples it (whose objective is at most F0 / 2), and a larger tilt ranks better.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

from pydantic import model_validator

from sim.props import PropDef
from sim.specbase import quantity
from sim.tasks.base import Pose, Task, TaskConfig, check_pose, pose_offsets
from sim.trajectory import MotionDef

#: Name of the block prop in the physics (and in the replay frames).
BLOCK = "block"
MAX_BLOCK_MASS_KG = 1000.0
#: Lightest block (kg): ODE refuses a body of a few micrograms (dMassCheck aborts the process).
MIN_BLOCK_MASS_KG = 1.0


class DominoConfig(TaskConfig):
    """`task: {type: domino, mass: kg, ready: {joint: deg}, push: {joint: deg}, width?: m,
    height?: m, distance?: m, friction?, ready_time?: s}`.

    width is the block's thickness along x, height its height (m); distance is the x of its
    near face (m, the ankles are at x = 0); friction its coefficient against the ground and the
    hands. The arms reach `ready` over [0, ready_time] and `push` over the task window (joint
    angles in degrees relative to the standing pose). The poses have no defaults: joint names
    are the character's, so they come from the spec (examples/domino.yaml has the humanoid's).
    """

    type: Literal["domino"] = "domino"
    PARAMETER_PATHS: ClassVar[dict[str, str]] = {"mass": "mass"}
    mass: quantity(MIN_BLOCK_MASS_KG, MAX_BLOCK_MASS_KG, "kg")
    width: quantity(0.02, 2.0, "m") = 0.15
    height: quantity(0.1, 5.0, "m") = 1.6
    distance: quantity(0.0, 3.0, "m") = 0.5
    friction: quantity(0.01, 5.0, "(coefficient)") = 0.8
    ready: Pose
    push: Pose
    ready_time: quantity(0.01, 10.0, "s") = 0.6

    @model_validator(mode="after")
    def _shape(self) -> DominoConfig:
        if self.width >= self.height:
            raise ValueError("width must be below height (a domino stands on its narrow face)")
        return self

    def check(self, spec: Any, character: Any) -> None:
        check_pose(self.ready, character, "task.ready")
        check_pose(self.push, character, "task.push")
        if self.ready_time > spec.clip.task_start + 1e-9:
            raise ValueError(f"task.ready_time: {self.ready_time:g} s ends after the "
                             f"preparation window ({spec.clip.task_start:g} s)")

    def parameters(self) -> dict[str, float]:
        return {"mass": self.mass}

    def build(self, spec: Any, character: Any) -> Task:
        return DominoTask(spec, character)


class DominoTask(Task):
    events = True

    def __init__(self, spec: Any, character: Any):
        super().__init__(spec, character)
        cfg: DominoConfig = spec.task
        self.config = cfg
        self.tip_angle = math.atan2(cfg.width, cfg.height)  # rad
        self.props = (PropDef(BLOCK, "box", (cfg.width, cfg.height), cfg.mass,
                              (cfg.distance + 0.5 * cfg.width, 0.5 * cfg.height),
                              friction=cfg.friction),)
        self.max_tilt = 0.0

    @property
    def motions(self) -> list[MotionDef]:
        cfg, clip = self.config, self.spec.clip
        return [(0.0, cfg.ready_time, pose_offsets(cfg.ready, self.character)),
                (clip.task_start, clip.duration, pose_offsets(cfg.push, self.character))]

    def tilt(self, physics: Any) -> float:
        """The block's forward tilt (rad, positive leaning away from the character)."""
        return -physics.prop(BLOCK).pose()[2]

    def reset(self, physics: Any) -> None:
        self.max_tilt = 0.0

    def after_step(self, physics: Any, t: float) -> None:
        tilt = self.tilt(physics)
        if tilt > self.max_tilt:
            self.max_tilt = tilt

    def success(self, physics: Any) -> bool:
        return self.tilt(physics) > self.tip_angle

    def penalty(self, physics: Any, scale: float) -> float:
        if self.success(physics):
            return 0.0
        progress = min(max(self.max_tilt / self.tip_angle, 0.0), 1.0)
        return scale * (0.5 + 0.5 * (1.0 - progress))
