"""`catch`: a heavy ball thrown to the character's held-out hands (paper 6.1.3, Figure 10).

The character holds the `hold` pose (degrees from the standing pose, e.g. both arms forward)
from the start of the clip; its standing lean is found with the arms out. A thrower stands
`throw.distance` m ahead of the hands at their height and releases the ball so that, on a
ballistic arc of `throw.flight` s, its centre reaches the hands' centre (as held at the clip
start) at `throw.arrival` (default: the task window's start). Until the release the ball is a
disabled ODE body at the release point.

The catch is a weld: after each step, as soon as the ball's centre is within `reach` m of the
contact distance (ball radius + hand radius) of a hand geom (the character file's `hands`), a
fixed joint is made between the ball and that hand's body (every hand within reach), at that
moment: the collision is perfectly inelastic, momentum is conserved, and the ball's weight is
then carried through the arms. The reactive controller does not know about the ball: its
weight and impact reach the character only through ODE. A ball that never comes within reach
flies on (it may hit the forearms or the ground). A clip whose ball was not caught gets a
penalty of 2 x the fall-penalty unit (sqrt(steps) x support length) on top of its objective,
so every miss ranks below every catch, fallen or not ("heavily penalizes solutions when it is
not feasible to catch the ball"). `task_success`: the ball is held at the end.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

from sim.dynamics import GRAVITY
from sim.props import PropDef
from sim.specbase import StrictModel, quantity
from sim.tasks.base import ClipTime, Pose, Task, TaskConfig, check_pose, pose_offsets

BALL = "ball"
#: The penalty of a missed ball, in units of the fall penalty's unit.
MISS_PENALTY_UNITS = 2.0


class Ball(StrictModel):
    """The ball: mass (kg) and radius (m); a 7 kg medicine ball is about 0.22 m across."""

    mass: quantity(0.05, 50.0, "kg") = 7.0
    radius: quantity(0.03, 0.4, "m") = 0.11


class Throw(StrictModel):
    """Where the ball comes from: released `distance` m ahead (+x) of the hands at their
    height, `flight` s before it reaches them at `arrival` (s from the clip start; default the
    task window's start)."""

    distance: quantity(0.1, 10.0, "m") = 2.0
    flight: quantity(0.1, 3.0, "s") = 0.7
    arrival: ClipTime | None = None


class CatchConfig(TaskConfig):
    """`task: {type: catch, hold: {joint: degrees}, ball?: {mass, radius}, throw?: {distance,
    flight, arrival}, reach?}`."""

    type: Literal["catch"] = "catch"
    NEEDS = ("hands",)
    PARAMETER_PATHS: ClassVar[dict[str, str]] = {"mass": "ball.mass"}
    hold: Pose
    ball: Ball = Ball()
    throw: Throw = Throw()
    reach: quantity(0.0, 0.2, "m") = 0.02

    def arrival(self, clip: Any) -> float:
        return self.throw.arrival if self.throw.arrival is not None else clip.task_start

    def check(self, spec: Any, character: Any) -> None:
        check_pose(self.hold, character, "task.hold")
        arrival = self.arrival(spec.clip)
        if arrival > spec.clip.length:
            raise ValueError("task.throw.arrival: after the end of the clip")
        if arrival - self.throw.flight < 0.0:
            raise ValueError("task.throw.flight: the ball would be released before the clip "
                             f"starts (arrival {arrival:g} s - flight {self.throw.flight:g} s)")

    def parameters(self) -> dict[str, float]:
        return {"mass": self.ball.mass}

    def build(self, spec: Any, character: Any) -> Task:
        return CatchTask(spec, character)


class CatchTask(Task):
    events = True

    def __init__(self, spec: Any, character: Any):
        super().__init__(spec, character)
        cfg: CatchConfig = spec.task
        self.cfg = cfg
        self.arrival = cfg.arrival(spec.clip)
        self.release = self.arrival - cfg.throw.flight
        self.props = (PropDef(BALL, "sphere", (cfg.ball.radius,), cfg.ball.mass, (0.0, 0.0)),)
        self.hands = [(name, character.geom(name)) for name in character.hands]
        self.caught_at: float | None = None
        self.released = False
        self._launch = ((0.0, 0.0), (0.0, 0.0))

    @property
    def initial_pose(self) -> dict[int, float]:
        return pose_offsets(self.cfg.hold, self.character)

    def reset(self, physics: Any) -> None:
        """Aim at the hands as they are held at the clip start; hold the ball at the release
        point, disabled, until the release."""
        self.caught_at = None
        self.released = False
        xs, ys = zip(*(physics.geoms[n].getPosition()[:2] for n, _g in self.hands), strict=True)
        hx, hy = sum(xs) / len(xs), sum(ys) / len(ys)
        d, t = self.cfg.throw.distance, self.cfg.throw.flight
        self._launch = ((hx + d, hy), (-d / t, 0.5 * GRAVITY * t))
        ball = physics.prop(BALL).body
        ball.setPosition((hx + d, hy, 0.0))
        ball.setLinearVel((0.0, 0.0, 0.0))
        ball.disable()

    def before_step(self, physics: Any, t: float) -> None:
        if not self.released and t >= self.release - 1e-9:
            ball = physics.prop(BALL).body
            (x, y), (vx, vy) = self._launch
            ball.setPosition((x, y, 0.0))
            ball.setLinearVel((vx, vy, 0.0))
            ball.enable()
            self.released = True

    def after_step(self, physics: Any, t: float) -> None:
        if self.caught_at is not None or not self.released:
            return
        bx, by, _ = physics.prop(BALL).body.getPosition()
        limit = self.cfg.ball.radius + self.cfg.reach
        bodies = []
        for name, g in self.hands:
            hx, hy, _ = physics.geoms[name].getPosition()
            if math.hypot(bx - hx, by - hy) <= limit + g.radius:
                body = self.character.body_names[g.body]
                if body not in bodies:
                    bodies.append(body)
        for body in bodies:
            physics.attach_prop(BALL, body)
        if bodies:
            self.caught_at = t

    def success(self, physics: Any) -> bool | None:
        return physics.attached(BALL)

    def penalty(self, physics: Any, scale: float) -> float:
        return 0.0 if physics.attached(BALL) else MISS_PENALTY_UNITS * scale
