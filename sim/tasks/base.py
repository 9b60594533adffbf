"""What a task type is: its spec model (`TaskConfig`) and its run-time object (`Task`).

A task type is one module of `sim.tasks` holding a `TaskConfig` subclass (a pydantic model
with a `type: Literal[...]` tag; its fields are the spec's `task:` block) and a `Task`
subclass, plus its entry in `sim.tasks.TASK_TYPES`. The spec's `task` field is the
discriminated union of every registered config.

Contract of a `TaskConfig`:
  * `needs()`: what the task needs of a character (`CHARACTER_NEEDS`: `hands`, `torso`);
    checked once, when the spec is parsed, for any character (`check_needs`), before `check`.
  * `check(spec, character)`: every rule that needs the rest of the spec or the character
    (joint and body names, windows inside the clip); raises ValueError whose message starts
    with the field's path (`task.target: ...`). Called once, when the spec is parsed.
  * `parameters()`: the numbers placing the task within its family (library keys).
  * `build(spec, character) -> Task`: the run-time object (pure Python, no ODE).

Contract of a `Task` (one per simulator; `reset` before each run):
  * `props`: the PropDefs the physics must hold (built once per simulator).
  * `motions`: reference pose changes (start s, duration s, {hinge index: offset rad}).
  * `tracks`: dense reference offsets (`sim.trajectory.FrameTrack`: frames at a constant
    rate, splined), added to the standing pose and the motions' targets.
  * `initial_pose`: {hinge index: offset rad} from the standing pose that the clip starts in
    and holds (e.g. hands held out); the standing lean is found with it.
  * `reset(physics)`; `before_step(physics, t)` (events: external forces, a throw) runs after
    the controller's torques are applied and before the step; `after_step(physics, t)` (a
    catch, a hit) runs after the step while its contacts are still readable. Both are called
    only when `events` is True.
  * `interaction_failed(physics, t) -> bool`, polled after `after_step` (tasks whose
    `reports_failure` is True, while a CMRT is held): True once the task knows that the
    interaction the anticipation was made for did not happen as expected (a punch that met
    nothing). The rollout then releases the CMRT (`sim.rollout.ReleasableCmrt`): the balance
    controller goes back to its own reference, purely reactive (paper 6.1.4, Figure 11 bottom).
  * `success(physics) -> bool | None` at the end (None: the task has no goal beyond balance);
    `penalty(physics, scale) -> float` (>= 0) is added to the objective; `scale` is the
    objective's fall-penalty unit (sqrt(steps) x support length).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from sim.props import PropDef
from sim.specbase import StrictModel, quantity
from sim.trajectory import FrameTrack, MotionDef

if TYPE_CHECKING:
    from sim.character import Character

#: A pose target's angles (degrees) must stay inside this range.
MAX_TARGET_DEGREES = 180.0
#: The longest clip (s, as sim.spec's): the bound of every time a task block sets.
MAX_CLIP_SECONDS = 20.0
#: The shortest motion (s): one simulation step (sim.physics.DT), as the clip's task window.
MIN_MOTION_SECONDS = 0.001
#: A joint angle of a pose target, degrees relative to the standing pose.
Angle = quantity(-MAX_TARGET_DEGREES, MAX_TARGET_DEGREES, "degrees")
#: {joint name: angle}: a pose target.
Pose = dict[str, Angle]
#: A time from the clip's start (s).
ClipTime = quantity(0.0, MAX_CLIP_SECONDS, "s")


#: What a task may need of a character, and the words that say it: each names the character
#: definition's field that provides it.
CHARACTER_NEEDS = {
    "hands": "hands (the geoms that hold or strike: its `hands`)",
    "torso": "a torso (the segment a push acts on: its `torso`)",
}


def check_pose(pose: dict[str, float], character: Character, where: str) -> None:
    """Joint names known to the character, angles in degrees within the joint's range."""
    for name, deg in pose.items():
        if name not in character.hinge_names:
            raise ValueError(f"{where}: unknown joint {name!r}; joints are "
                             f"{', '.join(character.hinge_names)}")
        if not -MAX_TARGET_DEGREES <= deg <= MAX_TARGET_DEGREES:
            raise ValueError(f"{where}: joint {name!r}: {deg} degrees is outside "
                             f"[{-MAX_TARGET_DEGREES:g}, {MAX_TARGET_DEGREES:g}]")


def pose_offsets(pose: dict[str, float], character: Character) -> dict[int, float]:
    """{hinge index: radians} of a pose target in degrees."""
    return {character.hinge_index(k): math.radians(v) for k, v in pose.items()}


class TaskConfig(StrictModel):
    """Base of every task type's spec block; see the module docstring."""

    type: str
    #: What this task type needs of a character (keys of `CHARACTER_NEEDS`).
    NEEDS: ClassVar[tuple[str, ...]] = ()

    def needs(self) -> tuple[str, ...]:
        """What this task needs of its character (`CHARACTER_NEEDS`' keys)."""
        return self.NEEDS

    def check_needs(self, character: Character, field: str) -> None:
        """ValueError naming the task and the character's field (`field`: where the spec
        holds the character, e.g. `character.definition`) when the character lacks a need."""
        have = {"hands": bool(character.hands), "torso": character.torso is not None}
        for need in self.needs():
            if not have[need]:
                raise ValueError(f"task.type: a {self.type} task needs a character with "
                                 f"{CHARACTER_NEEDS[need]}; {field}.{need}: character "
                                 f"{character.name!r} has none")

    def check(self, spec: Any, character: Character) -> None:
        return None

    #: Where each of `parameters()`'s library parameters lives in this task block, as a dotted
    #: path (`tire.mass`; a list index as a number, `punches.0.delay`). A parameter that is not
    #: one plain field (a push's signed force) is set by overriding `parameter_updates`.
    PARAMETER_PATHS: ClassVar[dict[str, str]] = {}

    def parameters(self) -> dict[str, float]:
        return {}

    def parameter_updates(self, key: str, value: float) -> dict[str, Any]:
        """The task block's fields to set (dotted path -> value) so that library parameter
        `key` becomes `value`; KeyError if this task has no such parameter."""
        return {self.PARAMETER_PATHS[key]: value}

    def build(self, spec: Any, character: Character) -> Task:
        raise NotImplementedError


class Task:
    """Run-time task: props, motions, events, success and penalty (module docstring)."""

    events = False
    #: True: the rollout polls `interaction_failed` (only tasks with `events`).
    reports_failure = False
    props: tuple[PropDef, ...] = ()

    def __init__(self, spec: Any, character: Character):
        self.spec = spec
        self.character = character

    @property
    def motions(self) -> list[MotionDef]:
        return []

    @property
    def tracks(self) -> list[FrameTrack]:
        return []

    @property
    def initial_pose(self) -> dict[int, float]:
        return {}

    def reset(self, physics: Any) -> None:
        return None

    def before_step(self, physics: Any, t: float) -> None:
        return None

    def after_step(self, physics: Any, t: float) -> None:
        return None

    def interaction_failed(self, physics: Any, t: float) -> bool:
        return False

    def success(self, physics: Any) -> bool | None:
        return None

    def penalty(self, physics: Any, scale: float) -> float:
        return 0.0
