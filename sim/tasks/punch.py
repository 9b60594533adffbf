"""`punch`: a punching bag hanging from a fixed anchor, hit by a fast punch (paper 6.1.4).

The arm motion is reference pose changes the balance controller tracks: the arms come up to a
guard in the preparation window (`guard`: one or more timed pose changes), then each entry of
`punches` is a fast pose change starting `delay` s into the task window (its duration defaults
to the window's; two entries make a double punch), and an optional `retract` pose change
follows the task window. The bag is a capsule prop (radius `radius`, cylinder
length `length`, mass `mass`) hanging by a rigid rod (`links: 0`) or a chain of `links` bodies
from an anchor `rope` metres above its centre; the bag's reaction reaches the character only
through ODE contacts with the character's contact geoms (hands, forearms): the reactive
controller does not model the bag.

Placement: the bag's centre is at height `height` and its near face is `distance` metres in
front of the support centre (the middle of the feet's heel-toe interval at the start), so a
bag out of reach is a larger `distance`.

Success: a hand (one of the geoms the character's file lists as `hands`) touched the bag during
the task window. A miss adds one fall-penalty unit to the objective, so that the optimiser
cannot make the punch easier by pulling the hand out of reach.

The expected interaction failed (`interaction_failed`, the rollout then releases the CMRT) when
no hand has touched the bag by the end of the earliest punch's pose change (or of the task
window, if that comes first): the arm is then at its target, fully extended, so that strike
can no longer meet the bag, and the anticipation made for its impact has nothing to act on
(paper 6.1.4, Figure 11 bottom: the bag absent or out of reach).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field

from sim.props import Hanging, PropDef
from sim.specbase import StrictModel, count, quantity
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

BAG = "bag"
MAX_BAG_MASS_KG = 500.0
#: Lightest bag (kg): ODE refuses a body of a few micrograms (dMassCheck aborts the process).
MIN_BAG_MASS_KG = 1.0
MAX_MOTIONS = 8  # guard steps, punches
#: A contact point within this distance (m) of a hand sphere's surface is the hand's.
HAND_CONTACT_TOLERANCE = 0.005
#: s: clip times within this of each other are the same instant (steps are 1 ms).
TIME_TOLERANCE = 1e-9


class Guard(StrictModel):
    """A step of the guard: `target` (degrees relative to the standing pose) reached by a
    quintic ease over `duration` s from `start` s of the clip."""

    target: Pose
    start: ClipTime
    duration: quantity(MIN_MOTION_SECONDS, 5.0, "s")


class Strike(StrictModel):
    """A punch (or the retract): `target` (degrees relative to the standing pose) reached by a
    quintic ease over `duration` s, starting `delay` s after the task window starts (a punch)
    or ends (the retract). A punch's duration defaults to the task window, the retract's to
    half the decay."""

    target: Pose
    delay: quantity(0.0, 5.0, "s") = 0.0
    duration: quantity(MIN_MOTION_SECONDS, 5.0, "s") | None = None


class PunchConfig(TaskConfig):
    """`task: {type: punch, guard, punches, retract?, mass, distance, height, radius, length,
    rope, links}` (module docstring)."""

    type: Literal["punch"] = "punch"
    NEEDS = ("hands",)
    PARAMETER_PATHS: ClassVar[dict[str, str]] = {
        "mass": "mass", "distance": "distance", "height": "height",
        "punch_delay": "punches.0.delay"}
    guard: Annotated[list[Guard], Field(min_length=1, max_length=MAX_MOTIONS)]
    punches: Annotated[list[Strike], Field(min_length=1, max_length=MAX_MOTIONS)]
    retract: Strike | None = None
    mass: quantity(MIN_BAG_MASS_KG, MAX_BAG_MASS_KG, "kg") = 30.0
    distance: quantity(0.05, 5.0, "m") = 0.5
    height: quantity(0.3, 3.0, "m") = 1.35
    radius: quantity(0.02, 1.0, "m") = 0.18
    length: quantity(0.05, 3.0, "m") = 0.6
    rope: quantity(0.05, 5.0, "m") = 0.9
    links: count(0, 20, "links") = 0

    def punch_windows(self, clip: Any) -> list[tuple[float, float]]:
        """(start s, duration s) of every punch in clip time."""
        return [(clip.task_start + p.delay, p.duration if p.duration is not None
                 else clip.duration) for p in self.punches]

    def motion_windows(self, clip: Any) -> list[tuple[str, float, float, dict[str, float]]]:
        """(field path, start s, duration s, target) of every motion in clip time."""
        out = [(f"task.guard.{i}", g.start, g.duration, g.target)
               for i, g in enumerate(self.guard)]
        for i, (p, (start, dur)) in enumerate(zip(self.punches, self.punch_windows(clip),
                                                  strict=True)):
            out.append((f"task.punches.{i}", start, dur, p.target))
        if self.retract is not None:
            r = self.retract
            dur = r.duration if r.duration is not None else max(0.5 * clip.decay, 0.05)
            out.append(("task.retract", clip.task_end + r.delay, dur, r.target))
        return out

    def check(self, spec: Any, character: Any) -> None:
        if any(character.geom(h).shape != "sphere" for h in character.hands):
            raise ValueError("task: a punch needs the character's hand geoms to be spheres")
        for where, start, dur, target in self.motion_windows(spec.clip):
            check_pose(target, character, f"{where}.target")
            if start + dur > spec.clip.length + 1e-9:
                raise ValueError(f"{where}: the motion ends after the clip "
                                 f"({start + dur:g} s > {spec.clip.length:g} s)")
        if self.height - self.radius - 0.5 * self.length <= 0.0:
            raise ValueError("task.height: the bag's bottom would be below the ground")

    def parameters(self) -> dict[str, float]:
        return {"mass": self.mass, "distance": self.distance, "height": self.height,
                "punch_delay": self.punches[0].delay}

    def build(self, spec: Any, character: Any) -> Task:
        return PunchTask(spec, character)


class PunchTask(Task):
    """The bag prop, the arm motions, and the hit and miss detection (module docstring)."""

    events = True
    reports_failure = True

    def __init__(self, spec: Any, character: Any):
        # Here, not at the module's top: parsing a spec must not import ODE (sim/__init__.py).
        from sim.physics import PROP_CHARACTER

        super().__init__(spec, character)
        self._hand_kind = PROP_CHARACTER
        cfg: PunchConfig = spec.task
        self.config = cfg
        support_centre = 0.5 * (float(character.heel0[:, 0].min())
                                + float(character.toe0[:, 0].max()))
        x = support_centre + cfg.distance + cfg.radius
        self.bag = PropDef(
            name=BAG, shape="capsule", size=(cfg.radius, cfg.length), mass=cfg.mass,
            position=(x, cfg.height),
            hanging=Hanging(anchor=(x, cfg.height + cfg.rope), links=cfg.links))
        self.props = (self.bag,)
        self.window = (spec.clip.task_start, spec.clip.task_end)
        #: s: by then a hand should have met the bag (the earliest punch's end, at the latest
        #: the task window's: hits count only inside it).
        self.miss_time = min(min(start + dur for start, dur in cfg.punch_windows(spec.clip)),
                             spec.clip.task_end)
        self.hands = [(name, character.geom(name).radius) for name in character.hands]
        self.hit_time: float | None = None
        self.hit_hand: str | None = None
        self.peak_force = 0.0  # N, largest hand-bag contact force seen in the task window

    @property
    def motions(self) -> list[MotionDef]:
        return [(start, dur, pose_offsets(target, self.character))
                for _w, start, dur, target in self.config.motion_windows(self.spec.clip)]

    def reset(self, physics: Any) -> None:
        self.hit_time = None
        self.hit_hand = None
        self.peak_force = 0.0

    def after_step(self, physics: Any, t: float) -> None:
        if not self.window[0] <= t <= self.window[1] + 1e-9:
            return
        for c in physics.prop_contact_list():  # a hand-bag contact is a prop contact
            if c.kind != self._hand_kind or c.a != BAG:
                continue
            hand = self.hand_at(physics, c.point)
            if hand is None:
                continue
            self.peak_force = max(self.peak_force, math.hypot(*c.force))
            if self.hit_time is None:
                self.hit_time, self.hit_hand = t, hand

    def hand_at(self, physics: Any, point: tuple[float, float]) -> str | None:
        """The hand whose sphere's surface the contact point lies on, if any."""
        for name, radius in self.hands:
            gx, gy, _ = physics.geoms[name].getPosition()
            if math.hypot(point[0] - gx, point[1] - gy) <= radius + HAND_CONTACT_TOLERANCE:
                return name
        return None

    def interaction_failed(self, physics: Any, t: float) -> bool:
        """No hand on the bag by `miss_time` (module docstring)."""
        return self.hit_time is None and t >= self.miss_time - TIME_TOLERANCE

    def success(self, physics: Any) -> bool | None:
        return self.hit_time is not None

    def penalty(self, physics: Any, scale: float) -> float:
        return 0.0 if self.hit_time is not None else scale
