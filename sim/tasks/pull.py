"""`pull`: a heavy box resting on the ground, pulled toward the character through a chain held
in its hands (paper 6.1.6, Figure 13: a 180 kg character pulls a 35 kg object by a 2.25 kg chain).

The box is a box prop on the ground with its near face `distance` m in front of the ankles
(x = 0). The chain is `chain.links` capsule props of equal length (`chain.length` / links, the
chain's mass shared equally), joined end to end by z-axis hinges (ODE joints made at every
reset and kept referenced by the physics); its first link is hinged to the body of every hand
geom (the grip, at the hands' centre) and its last to the middle of the box's near face. At the
clip start the chain hangs slack between the hands (held in the `hold` pose from the start,
the standing lean found with it) and the box: its joints lie on a parabola through both ends,
equally spaced along it, the sag chosen so that the links fit exactly (a chain longer than the
straight line from the hands to the box is a spec error naming `task.chain.length`).

The pull is a reference pose change of the arms, nothing else: over the task window they move
from `hold` to `pull` (degrees relative to the standing pose). The controller tracks it and
does not model the chain or the box: the chain's tension reaches the character only through
the hinges at its hands, and the box moves only if that tension beats its friction on the
ground.

Success (`Evaluation.task_success`): the box's centre ended at least `success` m closer to the
character than it started (toward -x). A clip that ends without that gets a penalty of
(1/2 + gap / 2) x the objective's fall unit F0, gap = 1 - (largest displacement toward the
character / `success`, capped to [0, 1]): a candidate that stands but leaves the box in place
ranks below every candidate that stands and pulls it, and a longer pull ranks better.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Any, ClassVar, Literal

import numpy as np

from sim.dynamics import ModelArrays, forward_kinematics
from sim.props import PropDef
from sim.specbase import StrictModel, count, quantity
from sim.standing import standing_state
from sim.tasks.base import Pose, Task, TaskConfig, check_pose, pose_offsets
from sim.trajectory import MotionDef

#: Names of the props in the physics (and in the replay frames): the box and the links.
BOX = "box"
LINK = "chain"
MAX_BOX_MASS_KG = 500.0
#: Lightest box (kg): ODE refuses a body of a few micrograms (dMassCheck aborts the process).
MIN_BOX_MASS_KG = 1.0
#: A chain whose links lie on a parabola of this sag (m) or more is not "held between".
MAX_SAG = 2.0


class Chain(StrictModel):
    """The chain: total mass (kg), number of links, total length (m), link radius (m)."""

    mass: quantity(0.1, 50.0, "kg") = 2.25
    links: count(2, 20, "links") = 6
    length: quantity(0.1, 5.0, "m") = 1.4
    radius: quantity(0.005, 0.05, "m") = 0.015


class PullConfig(TaskConfig):
    """`task: {type: pull, mass: kg, hold: {joint: deg}, pull: {joint: deg}, chain?: {mass,
    links, length, radius}, width?: m, height?: m, distance?: m, friction?, success?: m}`.

    mass, width (along x) and height are the box's, distance the x of its near face (m, the
    ankles at x = 0), friction its coefficient against the ground; `success` the displacement
    toward the character (m) that counts as pulled. The poses have no defaults: joint names
    are the character's (the example specs carry them)."""

    type: Literal["pull"] = "pull"
    NEEDS = ("hands",)
    PARAMETER_PATHS: ClassVar[dict[str, str]] = {"mass": "mass", "chain_mass": "chain.mass"}
    mass: quantity(MIN_BOX_MASS_KG, MAX_BOX_MASS_KG, "kg")
    chain: Chain = Chain()
    width: quantity(0.05, 2.0, "m") = 0.5
    height: quantity(0.05, 2.0, "m") = 0.3
    distance: quantity(0.0, 5.0, "m") = 1.5
    friction: quantity(0.01, 5.0, "(coefficient)") = 0.6
    success: quantity(0.01, 2.0, "m") = 0.05
    hold: Pose
    pull: Pose

    def check(self, spec: Any, character: Any) -> None:
        check_pose(self.hold, character, "task.hold")
        check_pose(self.pull, character, "task.pull")
        grip = grip_point(character, pose_offsets(self.hold, character))
        if not all(math.isfinite(v) for v in grip):
            raise ValueError("task.hold: no balanced standing pose holds the arms there")
        anchor = self.anchor
        if grip[0] >= anchor[0]:
            raise ValueError(f"task.distance: the box ({anchor[0]:.3f} m) must be ahead of the "
                             f"hands ({grip[0]:.3f} m)")
        chord = math.dist(grip, anchor)
        if self.chain.length <= chord + 1e-6:
            raise ValueError(f"task.chain.length: {self.chain.length:g} m does not reach from "
                             f"the hands to the box ({chord:.3f} m)")
        try:
            chain_points(grip, anchor, self.chain.links, self.chain.length)
        except ValueError as err:
            raise ValueError(f"task.chain.length: {err}") from None

    @property
    def anchor(self) -> tuple[float, float]:
        """Where the chain is fixed to the box: the middle of its near face (m)."""
        return (self.distance, 0.5 * self.height)

    def parameters(self) -> dict[str, float]:
        return {"mass": self.mass, "chain_mass": self.chain.mass}

    def build(self, spec: Any, character: Any) -> Task:
        return PullTask(spec, character)


def grip_point(character: Any, pose: dict[int, float]) -> tuple[float, float]:
    """The hands' centre (m, world) in the standing state held in `pose` (the rollout's own
    standing solution, before the contacts' static sink of a fraction of a millimetre)."""
    arrays = ModelArrays.from_character(character)
    q = standing_state(character, arrays, pose)
    alpha, p, _o = forward_kinematics(q, arrays.parent, arrays.a_par, arrays.a_chi)
    xs, ys = [], []
    for name in character.hands:
        g = character.geom(name)
        rel = np.asarray(g.a) - character.com0[g.body]
        c, s = math.cos(alpha[g.body]), math.sin(alpha[g.body])
        xs.append(p[g.body, 0] + c * rel[0] - s * rel[1])
        ys.append(p[g.body, 1] + s * rel[0] + c * rel[1])
    return float(sum(xs) / len(xs)), float(sum(ys) / len(ys))


def chain_points(a: tuple[float, float], b: tuple[float, float], links: int,
                 length: float) -> list[tuple[float, float]]:
    """links + 1 joint points from `a` to `b`, consecutive ones `length / links` apart, on the
    parabola through a and b that sags by s at its middle (s found by bisection)."""
    ell = length / links
    (ax, ay), (bx, by) = a, b

    def point(u: float, s: float) -> tuple[float, float]:
        return ax + u * (bx - ax), ay + u * (by - ay) - 4.0 * s * u * (1.0 - u)

    def march(s: float) -> tuple[float, list[tuple[float, float]]]:
        u, pts = 0.0, [a]
        for _ in range(links):
            lo, hi = u, u + 1.0
            p0 = point(u, s)
            for _ in range(60):  # the next point at chord ell along the parabola
                mid = 0.5 * (lo + hi)
                if math.dist(point(mid, s), p0) < ell:
                    lo = mid
                else:
                    hi = mid
            u = 0.5 * (lo + hi)
            pts.append(point(u, s))
        return u, pts

    lo, hi = 0.0, MAX_SAG
    if march(hi)[0] > 1.0:
        raise ValueError(f"{length:g} m would hang more than {MAX_SAG:g} m below the line "
                         "from the hands to the box")
    for _ in range(60):  # more sag uses more chain: the last point reaches u = 1
        mid = 0.5 * (lo + hi)
        if march(mid)[0] > 1.0:
            lo = mid
        else:
            hi = mid
    pts = march(0.5 * (lo + hi))[1]
    pts[-1] = b
    return pts


class PullTask(Task):
    events = True

    def __init__(self, spec: Any, character: Any):
        super().__init__(spec, character)
        cfg: PullConfig = spec.task
        self.config = cfg
        self.grip = grip_point(character, self.initial_pose)
        self.points = chain_points(self.grip, cfg.anchor, cfg.chain.links, cfg.chain.length)
        n, r = cfg.chain.links, cfg.chain.radius
        ell = cfg.chain.length / n
        links = []
        for k in range(n):
            (x0, y0), (x1, y1) = self.points[k], self.points[k + 1]
            # A capsule's axis is its local y: turn it from +y onto the link's direction.
            angle = math.atan2(y1 - y0, x1 - x0) - 0.5 * math.pi
            links.append(PropDef(f"{LINK}{k}", "capsule", (r, max(ell - 2.0 * r, 1e-3)),
                                 cfg.chain.mass / n, (0.5 * (x0 + x1), 0.5 * (y0 + y1)),
                                 angle=angle))
        box = PropDef(BOX, "box", (cfg.width, cfg.height), cfg.mass,
                      (cfg.distance + 0.5 * cfg.width, 0.5 * cfg.height), friction=cfg.friction)
        self.props = (box, *links)
        self.link_names = [d.name for d in links]
        self.hand_bodies = list(dict.fromkeys(
            character.body_names[character.geom(h).body] for h in character.hands))
        self.box_x0 = box.position[0]
        self.max_pull = 0.0

    @cached_property
    def _offsets(self) -> tuple[dict[int, float], dict[int, float]]:
        return (pose_offsets(self.config.hold, self.character),
                pose_offsets(self.config.pull, self.character))

    @property
    def initial_pose(self) -> dict[int, float]:
        return self._offsets[0]

    @property
    def motions(self) -> list[MotionDef]:
        hold, pull = self._offsets
        clip = self.spec.clip
        # The reference starts from the held pose (the clip's initial state), so a motion's
        # offsets are from it: `pull` is given from the standing pose, like `hold`.
        target = {j: off - hold.get(j, 0.0) for j, off in pull.items()}
        return [(clip.task_start, clip.duration, target)]

    def reset(self, physics: Any) -> None:
        """Join the chain: hands - link 0 - ... - last link - box, each hinge at the joint
        point between them as the props lie (no initial joint error)."""
        self.max_pull = 0.0
        pts, names = self.points, self.link_names
        for body in self.hand_bodies:
            physics.join(names[0], body, pts[0])
        for k in range(1, len(names)):
            physics.join(names[k], names[k - 1], pts[k])
        physics.join(BOX, names[-1], pts[-1])

    def displacement(self, physics: Any) -> float:
        """How far (m) the box's centre has moved toward the character (-x) since the start."""
        return self.box_x0 - physics.prop(BOX).pose()[0]

    def after_step(self, physics: Any, t: float) -> None:
        d = self.displacement(physics)
        if d > self.max_pull:
            self.max_pull = d

    def success(self, physics: Any) -> bool:
        return self.displacement(physics) >= self.config.success

    def penalty(self, physics: Any, scale: float) -> float:
        if self.success(physics):
            return 0.0
        progress = min(max(self.max_pull / self.config.success, 0.0), 1.0)
        return scale * (0.5 + 0.5 * (1.0 - progress))
