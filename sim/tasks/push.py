"""`push`: a horizontal external force on a body of the character for a time window."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from sim.specbase import quantity
from sim.tasks.base import MIN_MOTION_SECONDS, ClipTime, Task, TaskConfig

MAX_FORCE_N = 5000.0
#: Weakest push (N).
MIN_FORCE_N = 1.0


class PushConfig(TaskConfig):
    """`task: {type: push, force: N, direction: forward|backward, body?, start?, duration?}`.

    `body` defaults to the character's torso (`torso` in its file); the window (`start` s from
    the clip start, `duration` s) defaults to the task window.
    """

    type: Literal["push"] = "push"
    force: quantity(MIN_FORCE_N, MAX_FORCE_N, "N")
    direction: Literal["forward", "backward"] = "forward"
    body: Annotated[str, Field(min_length=1, max_length=100)] | None = None
    start: ClipTime | None = None
    duration: quantity(MIN_MOTION_SECONDS, 5.0, "s") | None = None

    def window(self, clip: Any) -> tuple[float, float]:
        """(start, duration) of the push in seconds; defaults to the task window."""
        start = self.start if self.start is not None else clip.task_start
        dur = self.duration if self.duration is not None else clip.duration
        return start, dur

    @property
    def signed_force(self) -> float:
        return self.force if self.direction == "forward" else -self.force

    def needs(self) -> tuple[str, ...]:
        """A push on no named `body` acts on the character's torso."""
        return ("torso",) if self.body is None else ()

    def check(self, spec: Any, character: Any) -> None:
        if self.body is not None and self.body not in character.body_names:
            raise ValueError(f"task.body: unknown body {self.body!r}; bodies are "
                             f"{', '.join(character.body_names)}")
        start, dur = self.window(spec.clip)
        if start + dur > spec.clip.length + 1e-9:
            raise ValueError("task: push start + duration exceeds the clip length")

    def parameters(self) -> dict[str, float]:
        return {"force": self.signed_force}

    def parameter_updates(self, key: str, value: float) -> dict[str, Any]:
        if key != "force":
            raise KeyError(key)
        # the library's force is signed: its sign is the push's direction
        return {"force": abs(value), "direction": "forward" if value >= 0 else "backward"}

    def build(self, spec: Any, character: Any) -> Task:
        return PushTask(spec, character)


class PushTask(Task):
    events = True

    def __init__(self, spec: Any, character: Any):
        super().__init__(spec, character)
        cfg: PushConfig = spec.task
        start, dur = cfg.window(spec.clip)
        self.body = character.body_index(cfg.body) if cfg.body is not None else character.torso
        self.force = cfg.signed_force
        self.start, self.end = start, start + dur

    def before_step(self, physics: Any, t: float) -> None:
        if self.start <= t < self.end:
            physics.add_force(self.body, self.force)
