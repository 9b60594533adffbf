"""The bouncing tire shared by the `tire_hit` and `tire_dodge` task types (their own modules
`sim.tasks.tire_hit`, `sim.tasks.tire_dodge`): a bouncing tire flies at the character (paper
6.1.7-6.1.8, Figures 14-15: a 32 kg tire and a 180 kg quadruped standing on its hind feet).

The tire is a `disc` prop (an annulus turning in the plane, `sim.props`) whose contacts bounce
with its `restitution` (ground, the character's contact geoms). At `launch.release` (clip time,
s) it is let go with its centre `launch.distance` m ahead (+x) of the support centre and
`launch.height` m above the ground, moving `launch.toward` m/s toward the character (-x) and
`launch.vertical` m/s upward (negative: down); with `launch.rolling` it spins at the rate of a
wheel rolling that way (omega = toward / radius), so that touching the ground its contact point
does not slide and friction takes no energy from the bounce. Before the release it is a disabled
ODE body at the release point.

The character's motion is reference pose changes (`motions`: each a target in degrees relative
to the standing pose, reached by a quintic ease from `start` over `duration` s; defaults: the
task window), tracked by the balance controller, which does not model the tire: its impacts
reach the character only through ODE's contacts with the character's contact geoms.

* `tire_hit`: the fore-paws strike the tire. Success: one of the geoms the character file lists
  as `hands` touched the tire. A clip without that touch gets one fall-penalty unit (sqrt(steps)
  x support length) on top of its objective, so that the optimiser cannot stand by missing.
* `tire_dodge`: the character lowers itself to let the tire pass. Success: the tire never
  touched the character. A touch adds one fall-penalty unit.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

from pydantic import Field

from sim.props import PropDef
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

TIRE = "tire"
MAX_TIRE_MASS_KG = 200.0
#: Lightest tire (kg): ODE refuses a body of a few micrograms (dMassCheck aborts the process).
MIN_TIRE_MASS_KG = 1.0
MAX_MOTIONS = 8
#: The penalty of a failed hit or dodge, in units of the fall penalty's unit.
FAILED_TASK_PENALTY_UNITS = 1.0


class Tire(StrictModel):
    """The tire: mass (kg), outer and inner radius (m), restitution of its contacts (the
    rebound speed over the impact speed along the normal: a dropped tire rebounds to
    restitution^2 of its height), friction coefficient against the ground and the character.
    A 32 kg tire of 0.35 m outer radius is a small truck tyre."""

    mass: quantity(MIN_TIRE_MASS_KG, MAX_TIRE_MASS_KG, "kg") = 32.0
    radius: quantity(0.1, 0.8, "m") = 0.35
    inner_radius: quantity(0.01, 0.7, "m") = 0.22  # a disc of 0 inner radius is no tire
    restitution: quantity(0.0, 1.0, "(coefficient)") = 0.6
    friction: quantity(0.01, 5.0, "(coefficient)") = 0.8


class Launch(StrictModel):
    """Where and how the tire is let go (module docstring): clip time `release` (s), centre
    `distance` m ahead of the support centre and `height` m up, velocity `toward` the character
    (m/s, horizontal) and `vertical` (m/s, up positive), spinning as if rolling if `rolling`."""

    release: ClipTime = 0.0
    distance: quantity(0.1, 20.0, "m")
    height: quantity(0.01, 10.0, "m")
    toward: quantity(-20.0, 20.0, "m/s")
    vertical: quantity(-30.0, 30.0, "m/s")
    rolling: bool = True


class Motion(StrictModel):
    """A reference pose change: `target` (degrees relative to the standing pose) reached by a
    quintic ease over `duration` s from `start` s of the clip (defaults: the task window)."""

    target: Pose
    start: ClipTime | None = None
    duration: quantity(MIN_MOTION_SECONDS, 10.0, "s") | None = None


class TireConfig(TaskConfig):
    """Fields shared by `tire_hit` and `tire_dodge` (module docstring)."""

    PARAMETER_PATHS: ClassVar[dict[str, str]] = {
        "mass": "tire.mass", "speed": "launch.toward", "vertical": "launch.vertical",
        "height": "launch.height"}
    tire: Tire = Tire()
    launch: Launch
    motions: Annotated[list[Motion], Field(max_length=MAX_MOTIONS)] = []

    def motion_windows(self, clip: Any) -> list[tuple[str, float, float, dict[str, float]]]:
        """(field path, start s, duration s, target) of every motion in clip time."""
        return [(f"task.motions.{i}", m.start if m.start is not None else clip.task_start,
                 m.duration if m.duration is not None else clip.duration, m.target)
                for i, m in enumerate(self.motions)]

    def check(self, spec: Any, character: Any) -> None:
        if not self.tire.inner_radius < self.tire.radius:
            raise ValueError("task.tire.inner_radius: must be below task.tire.radius")
        if not self.launch.height > self.tire.radius:
            raise ValueError(f"task.launch.height: the tire's centre must be above its radius "
                             f"({self.tire.radius:g} m) so that it starts off the ground")
        if self.launch.release > spec.clip.length:
            raise ValueError("task.launch.release: after the end of the clip")
        for where, start, dur, target in self.motion_windows(spec.clip):
            check_pose(target, character, f"{where}.target")
            if start + dur > spec.clip.length + 1e-9:
                raise ValueError(f"{where}: the motion ends after the clip "
                                 f"({start + dur:g} s > {spec.clip.length:g} s)")

    def parameters(self) -> dict[str, float]:
        return {"mass": self.tire.mass, "speed": self.launch.toward,
                "vertical": self.launch.vertical, "height": self.launch.height}


class TireTask(Task):
    """The tire prop, its release, the motions, and the touch detection (module docstring)."""

    events = True

    def __init__(self, spec: Any, character: Any, hit: bool):
        # Here, not at the module's top: parsing a spec must not import ODE (sim/__init__.py).
        from sim.physics import PROP_CHARACTER

        super().__init__(spec, character)
        self._character_kind = PROP_CHARACTER
        cfg: TireConfig = spec.task
        self.cfg = cfg
        self.hit = hit
        tire, launch = cfg.tire, cfg.launch
        support_centre = 0.5 * (float(character.heel0[:, 0].min())
                                + float(character.toe0[:, 0].max()))
        self.position = (support_centre + launch.distance, launch.height)
        self.velocity = (-launch.toward, launch.vertical)
        # Rolling toward -x at speed v: the contact point's velocity v_x + omega R is zero.
        self.spin = launch.toward / tire.radius if launch.rolling else 0.0
        self.props = (PropDef(TIRE, "disc", (tire.radius, tire.inner_radius), tire.mass,
                              self.position, velocity=self.velocity,
                              angular_velocity=self.spin, friction=tire.friction,
                              restitution=tire.restitution),)
        self.release = launch.release
        self.paw_bodies = {character.body_names[character.geom(h).body]
                           for h in character.hands}
        self.released = False
        self.touch_time: float | None = None  # first contact with any of the character's geoms
        self.touch_body: str | None = None
        self.hit_time: float | None = None  # first contact with a hand (paw) geom's body
        self.peak_force = 0.0  # N, the largest tire-character contact force

    @property
    def motions(self) -> list[MotionDef]:
        return [(start, dur, pose_offsets(target, self.character))
                for _w, start, dur, target in self.cfg.motion_windows(self.spec.clip)]

    def reset(self, physics: Any) -> None:
        self.touch_time = self.touch_body = self.hit_time = None
        self.peak_force = 0.0
        self.released = self.release <= 0.0
        if not self.released:
            physics.prop(TIRE).body.disable()

    def before_step(self, physics: Any, t: float) -> None:
        if not self.released and t >= self.release - 1e-9:
            body = physics.prop(TIRE).body
            body.setPosition((*self.position, 0.0))
            body.setLinearVel((*self.velocity, 0.0))
            body.setAngularVel((0.0, 0.0, self.spin))
            body.enable()
            self.released = True

    def after_step(self, physics: Any, t: float) -> None:
        if not self.released:
            return
        for c in physics.prop_contact_list():  # a tire-character contact is a prop contact
            if c.kind != self._character_kind or c.a != TIRE:
                continue
            force = (c.force[0] ** 2 + c.force[1] ** 2) ** 0.5
            self.peak_force = max(self.peak_force, force)
            if self.touch_time is None:
                self.touch_time, self.touch_body = t, c.b
            if self.hit_time is None and c.b in self.paw_bodies:
                self.hit_time = t

    def success(self, physics: Any) -> bool | None:
        return self.hit_time is not None if self.hit else self.touch_time is None

    def penalty(self, physics: Any, scale: float) -> float:
        return 0.0 if self.success(physics) else FAILED_TASK_PENALTY_UNITS * scale
