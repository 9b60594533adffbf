"""A prop's ODE objects: the body, geom and planar joint that `sim.physics.Physics` makes of a
`sim.props.PropDef`, and (if it hangs) its rod or chain.

`sim.props` stays pure data, imported where specs are parsed (no ODE there); this module is
the ODE side and is imported with the physics only. Choices (docs/physics.md, "Props and their
contacts"): every prop is a dynamic body with its own Plane2DJoint and uniform-density inertia
about z; a free prop is re-projected onto a rotation about z after each step (`reproject`, as
ODE's demo_plane2d does); a hanging prop is kept in the plane by its z-axis hinges, its own
planar joint switched off.
"""

from __future__ import annotations

import math

import ode

from sim.props import PROP_DEPTH, Hanging, PropDef

#: Collision categories (ODE category / collide bits) before `Physics` gives every geom a bit
#: of its own: the ground, the character's geoms, the props.
CATEGORY_GROUND, CATEGORY_CHARACTER, CATEGORY_PROP = 1, 2, 4
#: A capsule geom's rotation that lays its local z axis (ODE's capsule axis) along world y.
CAPSULE_ALONG_Y = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)


class Prop:
    """A prop's ODE objects: its body, geom, plane joint and (if hanging) its rod or chain."""

    def __init__(self, world: ode.World, space: ode.Space, d: PropDef):
        self.definition = d
        self.name = d.name
        self.body = ode.Body(world)
        mass = ode.Mass()
        i = d.inertia
        mass.setParameters(d.mass, 0.0, 0.0, 0.0, i, i, i, 0.0, 0.0, 0.0)
        self.body.setMass(mass)
        if d.shape == "box":
            self.geom = ode.GeomBox(space, (d.size[0], d.size[1], PROP_DEPTH))
        elif d.shape in ("sphere", "disc"):  # a disc's section by the plane is this circle
            self.geom = ode.GeomSphere(space, d.size[0])
        else:
            self.geom = ode.GeomCapsule(space, d.size[0], d.size[1])
        self.geom.setBody(self.body)
        if d.shape == "capsule":
            self.geom.setOffsetRotation(CAPSULE_ALONG_Y)
        self.geom.setCategoryBits(CATEGORY_PROP)
        self.geom.setCollideBits(CATEGORY_GROUND | CATEGORY_CHARACTER | CATEGORY_PROP)
        self.plane = ode.Plane2DJoint(world)
        self.links: list[ode.Body] = []
        self.hang_joints: list[ode.HingeJoint] = []
        self._link_rest: list[tuple[float, float]] = []
        self.reset()
        if d.hanging is not None:
            self._hang(world, d.hanging)

    def _hang(self, world: ode.World, h: Hanging) -> None:
        """A rod (one hinge about z at the anchor) or a chain of `links` bodies spaced evenly
        on the anchor-prop segment, each hinged to the one above, the prop to the last."""
        (ax, ay), (px, py) = h.anchor, self.definition.position
        n = h.links
        length = math.hypot(px - ax, py - ay) / max(n, 1)
        for k in range(n):
            f = (k + 0.5) / n
            link = ode.Body(world)
            m = ode.Mass()
            i = h.link_mass * length * length / 12.0
            m.setParameters(h.link_mass, 0.0, 0.0, 0.0, i, i, i, 0.0, 0.0, 0.0)
            link.setMass(m)
            self.links.append(link)
            self._link_rest.append((ax + f * (px - ax), ay + f * (py - ay)))
        self._reset_links()
        chain = [*self.links, self.body]
        for k, b in enumerate(chain):
            j = ode.HingeJoint(world)
            j.attach(b, chain[k - 1] if k > 0 else ode.environment)
            f = k / max(n, 1)
            j.setAnchor((ax + f * (px - ax), ay + f * (py - ay), 0.0))
            j.setAxis((0.0, 0.0, 1.0))
            self.hang_joints.append(j)
        self.plane.attach(None, None)  # the hinges keep it in the plane

    def _reset_links(self) -> None:
        for link, (x, y) in zip(self.links, self._link_rest, strict=True):
            link.setPosition((x, y, 0.0))
            link.setQuaternion((1.0, 0.0, 0.0, 0.0))
            link.setLinearVel((0.0, 0.0, 0.0))
            link.setAngularVel((0.0, 0.0, 0.0))

    @property
    def free(self) -> bool:
        """Neither hanging nor attached: kept in the plane by its own Plane2DJoint."""
        return self.plane.getBody(0) is not None

    def reset(self) -> None:
        d = self.definition
        b = self.body
        b.setPosition((d.position[0], d.position[1], 0.0))
        half = 0.5 * d.angle
        b.setQuaternion((math.cos(half), 0.0, 0.0, math.sin(half)))
        b.setLinearVel((d.velocity[0], d.velocity[1], 0.0))
        b.setAngularVel((0.0, 0.0, d.angular_velocity))
        b.setForce((0.0, 0.0, 0.0))
        b.setTorque((0.0, 0.0, 0.0))
        b.enable()
        self._reset_links()
        if d.hanging is None:
            self.plane.attach(self.body, ode.environment)

    def close(self) -> None:
        for j in self.hang_joints:
            j.setFeedback(False)
        self.hang_joints.clear()

    def pose(self) -> tuple[float, float, float]:
        return body_pose(self.body)

    def reproject(self) -> None:
        """Keep a free prop's orientation a rotation about z (ODE's demo_plane2d)."""
        w, _x, _y, z = self.body.getQuaternion()
        n = math.hypot(w, z)
        self.body.setQuaternion((w / n, 0.0, 0.0, z / n))
        wz = self.body.getAngularVel()[2]
        self.body.setAngularVel((0.0, 0.0, wz))


def body_pose(body: ode.Body) -> tuple[float, float, float]:
    """(x, y, angle about z) of an ODE body's CoM, in m and rad."""
    x, y, _ = body.getPosition()
    R = body.getRotation()
    return x, y, math.atan2(R[3], R[0])
