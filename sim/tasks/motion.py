"""`motion`: track a dense joint-angle trajectory (a clip of frames, e.g. imported from mocap).

    task: {type: motion, rate: 60, start: 1.0, joints: [waist, shoulder_r],
           frames: [[0, 0], [-2.5, 3.1], ...], speed: 1.0, scale: 1.0}

Each frame gives one angle per named joint, in degrees relative to the standing pose (as every
task's pose targets); frame i plays at `start + i / (rate * speed)` s of the clip. The clip
starts in the first frame's pose (the standing lean is found with it) and holds it until
`start`; the reference then follows the clamped cubic spline through the frames (C2 inside,
zero velocity at both ends: `sim.trajectory.FrameTrack`) and holds the last frame after the
end. `speed` scales time (2 plays twice as fast), `scale` the offsets from the standing pose
(0.5: half the motion's amplitude): both are library parameters, so a family may vary a
motion's speed or amplitude. Joints not named keep their standing pose.

On the command line a spec may give the block from a file (`task: {type: motion, file:
motion.yaml}`, read by `cmrt.specfile`); a spec that reaches the simulator (and every request
to the service) carries the frames inline. `cmrt motion import` makes such a block from a BVH
clip (`sim.motion_import`, docs/motion.md).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from sim.specbase import SAMPLES, quantity
from sim.tasks.base import Angle, ClipTime, Task, TaskConfig
from sim.trajectory import FrameTrack

#: Highest frame rate (frames per s): mocap's usual 120 Hz, with room to spare.
MAX_RATE = 240.0
#: Most frames: the longest clip (sim.tasks.base.MAX_CLIP_SECONDS, 20 s) at the highest rate.
MAX_FRAMES = 4800
#: Most joints a motion names (a character has fewer hinges than this).
MAX_JOINTS = 64
#: Degrees a frame may pass a joint limit by (float rounding of an angle written at the limit).
LIMIT_TOLERANCE_DEGREES = 1e-6

JointName = Annotated[str, Field(min_length=1, max_length=64)]
Frame = Annotated[list[Angle], Field(min_length=1, max_length=MAX_JOINTS)]


class MotionConfig(TaskConfig):
    """`task: {type: motion, rate, start?, joints, frames, speed?, scale?}` (module docstring)."""

    type: Literal["motion"] = "motion"
    rate: quantity(1.0, MAX_RATE, "frames per s")
    #: Clip time of the first frame (s); default: the task window's start.
    start: ClipTime | None = None
    joints: Annotated[list[JointName], Field(min_length=1, max_length=MAX_JOINTS)]
    frames: Annotated[list[Frame], Field(min_length=2, max_length=MAX_FRAMES), SAMPLES]
    speed: quantity(0.1, 10.0, "(time scale: 2 plays the frames twice as fast)") = 1.0
    scale: quantity(0.0, 2.0, "(scale of the offsets from the standing pose)") = 1.0

    PARAMETER_PATHS: ClassVar[dict[str, str]] = {"speed": "speed", "scale": "scale"}

    @model_validator(mode="before")
    @classmethod
    def _no_file(cls, data: Any) -> Any:
        if isinstance(data, dict) and "file" in data:
            raise ValueError("`file` is read by the command line (cmrt simulate / optimize / "
                             "submit), which puts the frames inline; here give `joints` and "
                             "`frames` inline")
        return data

    def first_frame_time(self, clip: Any) -> float:
        """Clip time of the first frame (s)."""
        return self.start if self.start is not None else clip.task_start

    @property
    def interval(self) -> float:
        """Seconds between two frames as played."""
        return 1.0 / (self.rate * self.speed)

    @property
    def motion_seconds(self) -> float:
        """Seconds from the first frame to the last, as played."""
        return (len(self.frames) - 1) * self.interval

    def check(self, spec: Any, character: Any) -> None:
        names = character.hinge_names
        for k, name in enumerate(self.joints):
            if name not in names:
                raise ValueError(f"task.joints.{k}: unknown joint {name!r}; joints are "
                                 f"{', '.join(names)}")
            if name in self.joints[:k]:
                raise ValueError(f"task.joints.{k}: joint {name!r} is named twice")
        for i, row in enumerate(self.frames):
            if len(row) != len(self.joints):
                raise ValueError(f"task.frames.{i}: has {len(row)} angles; `joints` names "
                                 f"{len(self.joints)}")
        t0, length = self.first_frame_time(spec.clip), spec.clip.length
        if t0 + self.motion_seconds > length + 1e-9:
            raise ValueError(
                f"task.frames: {len(self.frames)} frames at {self.rate:g} frames per s "
                f"(speed {self.speed:g}) last {self.motion_seconds:g} s; from the start at "
                f"{t0:g} s they end after the clip ({length:g} s)")
        self._check_limits(character)

    def _check_limits(self, character: Any) -> None:
        """Every frame's angle (standing pose + scale x offset) inside its joint's limits."""
        idx = [character.hinge_index(n) for n in self.joints]
        standing = np.degrees(character.standing_offsets[idx])
        lo, hi = np.degrees(character.limits[idx]).T
        angle = standing + self.scale * np.asarray(self.frames, dtype=float)
        bad = (angle < lo - LIMIT_TOLERANCE_DEGREES) | (angle > hi + LIMIT_TOLERANCE_DEGREES)
        if bad.any():
            i, k = (int(v) for v in np.argwhere(bad)[0])
            raise ValueError(
                f"task.frames.{i}.{k}: joint {self.joints[k]!r} at {self.frames[i][k]:g} "
                f"degrees from the standing pose (x scale {self.scale:g}, {angle[i, k]:.6g} "
                f"from the zero pose) is outside its limits [{lo[k]:g}, {hi[k]:g}]; "
                f"{int(bad.sum())} angles are")

    def parameters(self) -> dict[str, float]:
        return {"speed": self.speed, "scale": self.scale}

    def build(self, spec: Any, character: Any) -> Task:
        return MotionTask(spec, character)


class MotionTask(Task):
    """The motion's first frame as the initial pose, the rest as one frame track."""

    def __init__(self, spec: Any, character: Any):
        super().__init__(spec, character)
        cfg: MotionConfig = spec.task
        self.hinges = [character.hinge_index(n) for n in cfg.joints]
        self.offsets = np.radians(cfg.scale * np.asarray(cfg.frames, dtype=float))
        # The clip starts in the first frame (initial_pose): the track is the change from it.
        self.track = FrameTrack(cfg.first_frame_time(spec.clip), cfg.interval, self.hinges,
                                self.offsets - self.offsets[0])

    @property
    def initial_pose(self) -> dict[int, float]:
        return {j: float(v) for j, v in zip(self.hinges, self.offsets[0], strict=True)}

    @property
    def tracks(self) -> list[FrameTrack]:
        return [self.track]

