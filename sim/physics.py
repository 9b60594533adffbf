"""The ODE world of a planar character and its props: bodies, joints, contacts, reset.

`Physics(character, props=())` builds the world once; `reset(q, qd)` puts the character in any
state and every prop back in its initial state (run-time joints removed), so one Physics serves
every run of a clip. Nothing here decides anything: the rollout (`sim.rollout`) asks for
contacts, applies torques and forces, steps, and reads back.

Choices, with the PyODE traps they avoid (docs/physics.md):
- `world.step` (dense LCP), not `quickStep`: quickStep's ground force was 0.3-2 % off, and the
  balance objective is a ground-force measurement.
- World CFM is tiny (1e-6) so hinges stay rigid; ground contacts get the paper's soft CFM 7e-5
  through `ContactSoftCFM`, `ContactApprox1` so that mu is a friction coefficient, bounce 0.
- The ground is the plane y = 0. Foot contacts are made directly at each foot's heel and toe
  points (one per edge) from the model's kinematics instead of colliding boxes: 2 contacts per
  foot, none redundant, no collision callback on the character's hot path.
- Hinges are attached (child, parent): ODE's angle is body1 minus body2, so `getAngle()` is the
  child's angle relative to the parent (counter-clockwise positive) and `addTorque(t)` puts +t on
  the child and -t on the parent. Axes are set in the zero pose, so ODE's zero is the model's.
- Contact joints live in JointGroups; feedback is switched off on each before `empty()`
  (feedback + empty() aborts the process). Run-time joints (a catch's fixed joint, a hanging
  prop's hinges) are kept in Python lists for as long as they hold (PyODE destroys a joint
  when its Python object dies) and have their feedback switched off before they are dropped.
- One Plane2DJoint on the character's root keeps its chain of z-axis hinges in the plane. Every
  free prop has its own Plane2DJoint, and after each step its orientation is re-projected onto
  a rotation about z and its x/y angular velocity zeroed (as ODE's demo_plane2d does: the joint
  does not correct rotational drift out of the plane). A prop fixed to the character or hanging
  from a hinge is kept in the plane by those joints, so its own Plane2DJoint is switched off
  (`attach(None, None)`) while they hold. A prop's ODE objects are `sim.prop_bodies.Prop`.
- Props collide (one `SimpleSpace`, category bits) with the ground, with each other and with
  the character's contact geoms (`geoms` in the character file: hands, forearms); the
  character's geoms collide with props only (the feet's ground contacts are made as above).
  ODE's box contacts come in pairs mirrored across the plane (z = +-depth / 2); only those at
  z >= 0 are kept and moved to z = 0 (trap 5). Prop contacts: mu = PROP_FRICTION_MU (or the
  prop's own) along the in-plane tangent, the same soft CFM as the feet, bounce 0 (a prop with a
  `restitution` bounces: ODE's bounce on a rigid contact; docs/physics.md, "Restitution").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ode

from sim.character import ROOT_DOF, Character
from sim.dynamics import GRAVITY, ModelArrays, forward_kinematics
from sim.errors import SimError
from sim.linalg import dot
from sim.prop_bodies import CATEGORY_CHARACTER, CATEGORY_GROUND, CATEGORY_PROP, Prop, body_pose
from sim.props import PropDef

DT = 0.001  # s, simulation step
WORLD_CFM = 1e-6
WORLD_ERP = 0.2
CONTACT_SOFT_CFM = 7e-5
FRICTION_MU = 1.0  # foot-ground friction coefficient
#: m/s: a prop impact slower than this along the normal does not bounce (ODE's bounce_vel):
#: a resting prop's contact stays plastic instead of chattering.
BOUNCE_MIN_SPEED = 0.05
#: CFM of a bouncing prop contact: hard, so that the rebound is the restitution's.
BOUNCE_CFM = 1e-8
CONTACT_MARGIN = 0.0005  # m: a heel/toe within this height of the ground gets a contact
#: Divergence: a body faster than this (m/s) or spinning faster than this (rad/s), or any
#: non-finite state, is not a simulation any more.
MAX_SPEED = 100.0
MAX_SPIN = 1000.0

#: Per-geom category bits (`Physics._assign_collision_bits`) fit ODE's unsigned long.
MAX_COLLISION_BITS = 63

#: Contact kinds reported by `Physics.contact_list`.
FOOT_GROUND, PROP_GROUND, PROP_PROP, PROP_CHARACTER = (
    "foot-ground", "prop-ground", "prop-prop", "prop-character")


#: A hinge whose range comes this close (rad) to +-180 deg gets its ODE zero moved.
WRAP_MARGIN = math.radians(20.0)


def hinge_zero(lo: float, hi: float) -> float:
    """The model angle (rad) at which ODE's zero of a hinge with range [lo, hi] is placed.

    ODE measures a hinge angle in (-180, 180] deg from the pose at which its axis was set, and
    its stops compare that angle with the limits. A range reaching +-180 (the shoulders' ends at
    180) wraps: past 180 ODE reads -180 + x, below the low stop, and the stop's correction
    pumps energy in (741 J -> 7342 J in 10 ms). Such a hinge gets its ODE zero at the middle of
    its range, so the wrap point lies outside the range by at least half of what the range
    leaves of the circle; every other hinge keeps its zero at the model's (0, bit for bit)."""
    if lo > -math.pi + WRAP_MARGIN and hi < math.pi - WRAP_MARGIN:
        return 0.0
    if hi - lo > 2.0 * math.pi - 2.0 * WRAP_MARGIN:
        raise SimError(f"a hinge range of {math.degrees(hi - lo):.0f} deg cannot be kept "
                       f"{math.degrees(WRAP_MARGIN):.0f} deg off ODE's +-180 deg wrap")
    return 0.5 * (lo + hi)


_GET_ANGLE = ode.HingeJoint.getAngle
_GET_ANGLE_RATE = ode.HingeJoint.getAngleRate
_ADD_TORQUE = ode.HingeJoint.addTorque


class DivergenceError(SimError):
    """ODE's state became non-finite or absurdly fast: the step is not physics any more."""


@dataclass(frozen=True)
class ContactForce:
    """One contact after a step: the force (N, world x, y) on body `a` at `point` (m);
    `b` is None for the ground."""

    kind: str
    a: str
    b: str | None
    point: tuple[float, float]
    force: tuple[float, float]


def _world() -> ode.World:
    """An empty world with gravity along -y and the world's ERP and CFM."""
    world = ode.World()
    world.setGravity((0.0, -GRAVITY, 0.0))
    world.setERP(WORLD_ERP)
    world.setCFM(WORLD_CFM)
    return world


def _foot_contact() -> ode.Contact:
    """The parameters of a foot's ground contact. Friction only along x (ContactFDir1 with
    mu2 = 0 drops the out-of-plane friction row, which the planar root constraint makes
    redundant)."""
    c = ode.Contact()
    c.setMode(ode.ContactApprox1 | ode.ContactSoftCFM | ode.ContactMu2 | ode.ContactFDir1)
    c.setMu(FRICTION_MU)
    c.setMu2(0.0)
    c.setFDir1((1.0, 0.0, 0.0))
    c.setBounce(0.0)
    c.setSoftCFM(CONTACT_SOFT_CFM)
    return c


def _plastic_prop_contact() -> ode.Contact:
    """The parameters of a plastic prop contact (its mu and direction are set per pair)."""
    c = ode.Contact()
    c.setMode(ode.ContactApprox1 | ode.ContactSoftCFM | ode.ContactMu2 | ode.ContactFDir1)
    c.setMu2(0.0)
    c.setBounce(0.0)
    c.setSoftCFM(CONTACT_SOFT_CFM)
    return c


class Physics:
    """One character and its props in an ODE world. Build once; `reset(q, qd)` for each run."""

    def __init__(self, character: Character, arrays: ModelArrays | None = None,
                 props: tuple[PropDef, ...] | list[PropDef] = ()):
        # The builders run in this order: ODE's bodies, joints and geoms keep the order in
        # which they were made, and the solver and the collision pass follow it.
        self.character = character
        self.arrays = arrays or ModelArrays.from_character(character)
        self.world = _world()
        self.bodies: list[ode.Body] = self._build_bodies()
        self.hinges: list[ode.HingeJoint] = []
        #: (hinge index, model angle of ODE's zero) of the hinges whose range reaches near
        #: +-180 deg: their ODE zero sits at the middle of the range (see `hinge_zero`).
        self.hinge_zeros: list[tuple[int, float]] = []
        self._build_hinges()
        self._torque_limits = character.torque_limits.tolist()
        self._torque_limit_array = np.array(self._torque_limits, dtype=float)
        self._neg_torque_limit_array = -self._torque_limit_array  # (not negated every step)
        self.plane = ode.Plane2DJoint(self.world)
        self.plane.attach(self.bodies[0], ode.environment)
        self.contact_group = ode.JointGroup()
        self.contacts: list[tuple[ode.ContactJoint, int, float]] = []
        self._contact = _foot_contact()
        #: q then qd, read from ODE by `read_state`; `q` and `qd` are views of it.
        self._state = np.zeros(2 * character.ndof)
        self.q, self.qd = self._state[:character.ndof], self._state[character.ndof:]
        self._root = self.bodies[0]
        self._build_collision_space()
        self._build_props(props)
        #: Joints made at run time (a catch's weld, a chain's hinges): (joint, prop name,
        #: body or prop name), kept referenced (PyODE destroys a joint whose object dies).
        self.attachments: list[tuple[ode.FixedJoint | ode.HingeJoint, str, str]] = []
        self._pair_bits: list[tuple[ode.GeomObject, int, int]] | None = None
        self._owner_bit: dict[str, int] = {}
        self._assign_collision_bits()

    def _build_bodies(self) -> list[ode.Body]:
        """One ODE body per segment at its zero-pose CoM, with its mass and z inertia."""
        ch = self.character
        bodies = []
        for b in range(ch.n_bodies):
            body = ode.Body(self.world)
            mass = ode.Mass()
            i = float(ch.inertia[b])
            mass.setParameters(float(ch.mass[b]), 0.0, 0.0, 0.0, i, i, i, 0.0, 0.0, 0.0)
            body.setMass(mass)
            body.setPosition((float(ch.com0[b, 0]), float(ch.com0[b, 1]), 0.0))
            bodies.append(body)
        return bodies

    def _build_hinges(self) -> None:
        """A z-axis hinge (child, parent) per non-root body at its anchor, its stops at the
        joint's limits relative to its ODE zero (`hinge_zero`)."""
        ch = self.character
        for b in range(1, ch.n_bodies):
            j = ode.HingeJoint(self.world)
            j.attach(self.bodies[b], self.bodies[ch.parent[b]])
            lo, hi = ch.limits[b - 1]
            zero = hinge_zero(float(lo), float(hi))
            child = self.bodies[b]
            if zero != 0.0:  # set the axis with the child turned by `zero` about its anchor
                ax, ay = ch.anchor0[b]
                cx, cy = ch.com0[b] - ch.anchor0[b]
                c, sn = math.cos(zero), math.sin(zero)
                child.setPosition((float(ax + c * cx - sn * cy), float(ay + sn * cx + c * cy),
                                   0.0))
                child.setQuaternion((math.cos(0.5 * zero), 0.0, 0.0, math.sin(0.5 * zero)))
                self.hinge_zeros.append((b - 1, zero))
            j.setAnchor((float(ch.anchor0[b, 0]), float(ch.anchor0[b, 1]), 0.0))
            j.setAxis((0.0, 0.0, 1.0))
            if zero != 0.0:
                child.setPosition((float(ch.com0[b, 0]), float(ch.com0[b, 1]), 0.0))
                child.setQuaternion((1.0, 0.0, 0.0, 0.0))
            j.setParam(ode.ParamLoStop, float(lo) - zero)
            j.setParam(ode.ParamHiStop, float(hi) - zero)
            self.hinges.append(j)

    def _build_collision_space(self) -> None:
        """The collision space with the ground plane and the character's contact geoms
        (props against the ground, each other and those geoms)."""
        ch = self.character
        self.space = ode.SimpleSpace()
        self.ground = ode.GeomPlane(self.space, (0.0, 1.0, 0.0), 0.0)
        self.ground.setCategoryBits(CATEGORY_GROUND)
        self.ground.setCollideBits(CATEGORY_PROP)
        self.geoms: dict[str, ode.GeomObject] = {}
        self._geom_owner: dict[int, str] = {id(self.ground): "ground"}
        for k, g in enumerate(ch.geoms):
            geom = self._character_geom(g)
            self.geoms[g.name or f"{ch.body_names[g.body]}.geom{k}"] = geom
            self._geom_owner[id(geom)] = ch.body_names[g.body]

    def _build_props(self, props: tuple[PropDef, ...] | list[PropDef]) -> None:
        """The props' ODE objects (names unique among bodies and props), their look-ups,
        and the joint group and contact parameters of their contacts."""
        self.props: list[Prop] = [Prop(self.world, self.space, d) for d in props]
        names = list(self.character.body_names)
        for p in self.props:
            if p.name in names:
                raise SimError(f"prop {p.name!r}: the name is taken by a body or prop")
            names.append(p.name)
            self._geom_owner[id(p.geom)] = p.name
        self._prop_by_name = {p.name: p for p in self.props}
        self._prop_bodies = [p.body for p in self.props]
        self._prop_bodies += [link for p in self.props for link in p.links]
        self._body_index = {n: i for i, n in enumerate(self.character.body_names)}
        self.prop_group = ode.JointGroup()
        self.prop_contacts: list[tuple[ode.ContactJoint, str, str, str | None,
                                       tuple[float, float]]] = []
        self._prop_contact = _plastic_prop_contact()
        self._bounce_contacts: dict[float, ode.Contact] = {}

    def _assign_collision_bits(self) -> None:
        """One category bit per geom of the space, collide bits listing the geoms each may
        touch (the ground and the character's geoms: every prop; a prop: the ground, the
        character's geoms and the other props), as the shared category bits allowed. With a
        bit per geom, `_set_collide_bits` can also drop the pairs a run-time joint connects:
        `_near` returns at `areConnected` for those without making a contact, so ODE skipping
        them keeps every contact and its order, and saves a Python callback per pair and step
        (a pulled chain's 7 joined pairs). More geoms than bits: the shared bits stay."""
        ch_geoms = list(self.geoms.values())
        geoms = [self.ground, *ch_geoms, *(p.geom for p in self.props)]
        if len(geoms) > MAX_COLLISION_BITS:
            return
        bits = {id(g): 1 << i for i, g in enumerate(geoms)}
        prop_bits = sum(bits[id(p.geom)] for p in self.props)
        base = [(self.ground, bits[id(self.ground)], prop_bits)]
        base += [(g, bits[id(g)], prop_bits) for g in ch_geoms]
        ground_and_character = bits[id(self.ground)] | sum(bits[id(g)] for g in ch_geoms)
        base += [(p.geom, bits[id(p.geom)], ground_and_character | (prop_bits & ~bits[id(p.geom)]))
                 for p in self.props]
        self._pair_bits = base
        # name -> bits of its geoms: a prop's one geom, a body's geoms (none for most bodies)
        for g, bit, _mask in base[1:]:
            owner = self._geom_owner[id(g)]
            self._owner_bit[owner] = self._owner_bit.get(owner, 0) | bit
        for g, bit, mask in base:
            g.setCategoryBits(bit)
            g.setCollideBits(mask)

    def _set_collide_bits(self) -> None:
        """Collide bits without the pairs that the run-time joints connect (see
        `_assign_collision_bits`)."""
        if self._pair_bits is None:
            return
        drop: dict[int, int] = {}  # geom bit -> bits of the geoms it is joined to
        for _j, prop, other in self.attachments:
            a, b = self._owner_bit.get(prop, 0), self._owner_bit.get(other, 0)
            for x, y in ((a, b), (b, a)):
                k = x
                while k:
                    low = k & -k
                    drop[low] = drop.get(low, 0) | y
                    k ^= low
        for g, bit, mask in self._pair_bits:
            g.setCollideBits(mask & ~drop.get(bit, 0))

    def _character_geom(self, g) -> ode.GeomObject:
        body = self.bodies[g.body]
        com = self.character.com0[g.body]
        if g.shape == "sphere":
            geom = ode.GeomSphere(self.space, g.radius)
            mid = g.a
        else:
            dx, dy = g.b[0] - g.a[0], g.b[1] - g.a[1]
            length = math.hypot(dx, dy)
            geom = ode.GeomCapsule(self.space, g.radius, length)
            ux, uy = dx / length, dy / length
            mid = (0.5 * (g.a[0] + g.b[0]), 0.5 * (g.a[1] + g.b[1]))
        geom.setBody(body)
        # Body frames are parallel to the world's in the zero pose, where the file's geometry is.
        geom.setOffsetPosition((mid[0] - float(com[0]), mid[1] - float(com[1]), 0.0))
        if g.shape == "capsule":
            geom.setOffsetRotation((-uy, 0.0, ux, ux, 0.0, uy, 0.0, 1.0, 0.0))
        geom.setCategoryBits(CATEGORY_CHARACTER)
        geom.setCollideBits(CATEGORY_PROP)
        return geom

    # ---- state ------------------------------------------------------------------------
    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Put every body in the state (q, qd) and every prop in its initial state, with no
        contact and no run-time joint, without rebuilding the world."""
        self.clear_contacts()
        self.detach_all()
        a = self.arrays
        qd = np.zeros_like(q) if qd is None else qd
        alpha, p, o = forward_kinematics(q, a.parent, a.a_par, a.a_chi)
        omega = np.empty(len(alpha))
        omega[0] = qd[2]
        vel = np.empty_like(p)
        vel[0] = qd[:2]
        for b in range(1, len(alpha)):
            par = a.parent[b]
            omega[b] = omega[par] + qd[ROOT_DOF + b - 1]
            ro = o[b] - p[par]
            vo = vel[par] + omega[par] * np.array([-ro[1], ro[0]])
            rc = p[b] - o[b]
            vel[b] = vo + omega[b] * np.array([-rc[1], rc[0]])
        for b, body in enumerate(self.bodies):
            half = 0.5 * float(alpha[b])
            body.setPosition((float(p[b, 0]), float(p[b, 1]), 0.0))
            body.setQuaternion((math.cos(half), 0.0, 0.0, math.sin(half)))
            body.setLinearVel((float(vel[b, 0]), float(vel[b, 1]), 0.0))
            body.setAngularVel((0.0, 0.0, float(omega[b])))
            body.setForce((0.0, 0.0, 0.0))
            body.setTorque((0.0, 0.0, 0.0))
        for prop in self.props:
            prop.reset()
        self.read_state()

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Read q, qd from ODE: root CoM, root angle, then hinge angles and rates. The same
        two arrays (`q`, `qd`) every call, overwritten."""
        root = self._root
        x, y, _ = root.getPosition()
        R = root.getRotation()
        vx, vy, _ = root.getLinearVel()
        hinges = self.hinges
        # One list of q and qd written into their one buffer: a single conversion per step
        # (~0.5 us less than element and slice writes); `map` reads the hinges without a
        # Python loop.
        state = [x, y, math.atan2(R[3], R[0]), *map(_GET_ANGLE, hinges),
                 vx, vy, root.getAngularVel()[2], *map(_GET_ANGLE_RATE, hinges)]
        for i, zero in self.hinge_zeros:
            # Python's float sum is numpy's float64 sum (the same bits).
            state[ROOT_DOF + i] += zero
        self._state[:] = state
        return self.q, self.qd

    def pose_names(self) -> list[str]:
        """Names of the rows of `poses()`: the character's bodies, then props (and links)."""
        names = list(self.character.body_names)
        for p in self.props:
            names.append(p.name)
            names += [f"{p.name}.link{k}" for k in range(len(p.links))]
        return names

    def poses(self) -> list[tuple[float, float, float]]:
        """(x, y, angle) of every body, prop and chain link (rows as `pose_names()`)."""
        out = [body_pose(b) for b in self.bodies]
        for p in self.props:
            out.append(body_pose(p.body))
            out += [body_pose(link) for link in p.links]
        return out

    def prop(self, name: str) -> Prop:
        try:
            return self._prop_by_name[name]
        except KeyError:
            raise SimError(f"unknown prop {name!r}") from None

    def _all_bodies(self) -> list[ode.Body]:
        out = list(self.bodies)
        for p in self.props:
            out.append(p.body)
            out += p.links
        return out

    def diverged(self, qd: np.ndarray | None = None) -> str | None:
        """Why the state is not physics any more (non-finite, too fast), else None. With `qd`
        (the character's velocities just read) the character is judged by |qd| (SI units:
        m/s and rad/s together) against MAX_SPIN, and only the props are read from ODE."""
        if qd is not None:
            s = dot(qd, qd)
            if not s < MAX_SPIN * MAX_SPIN:
                return ("non-finite character state" if not math.isfinite(s)
                        else "character moving impossibly fast")
            bodies = self._prop_bodies
        else:
            bodies = self._all_bodies()
        for b in bodies:
            v = b.getLinearVel()
            w = b.getAngularVel()[2]
            x = b.getPosition()
            # A finite sum means every term is finite; only a non-finite sum (or an overflow)
            # needs the term-by-term test (one isfinite instead of seven, every 10 steps).
            if (not math.isfinite(v[0] + v[1] + v[2] + w + x[0] + x[1] + x[2])
                    and not all(math.isfinite(c) for c in (*v, w, *x))):
                return "non-finite state"
            if math.hypot(v[0], v[1]) > MAX_SPEED or abs(w) > MAX_SPIN:
                return "a body moving impossibly fast"
        return None

    # ---- actuation ---------------------------------------------------------------------
    def apply_torques(self, tau: np.ndarray) -> None:
        """Hinge torques (N m, +t on the child), each clamped to its joint's torque limit."""
        # np.maximum/np.minimum give the bits of Python's min(max(t, -lim), lim) (NaN
        # included) in ~1.5 us less per step than the per-hinge builtins; `map` calls
        # addTorque without a Python loop (this runs every 1 ms step).
        lim = self._torque_limit_array
        if len(tau) != len(self.hinges):
            raise ValueError(f"apply_torques: {len(tau)} torques for {len(self.hinges)} hinges")
        list(map(_ADD_TORQUE, self.hinges,
                 np.minimum(np.maximum(tau, self._neg_torque_limit_array), lim).tolist()))

    @property
    def torque_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(-limit, limit) per hinge (N m): the clamp of `apply_torques`, for a caller that
        clamps in a compiled call and hands the result to `add_clamped_torques`."""
        return self._neg_torque_limit_array, self._torque_limit_array

    def add_clamped_torques(self, tau: list[float]) -> None:
        """Hinge torques (N m, +t on the child) already clamped to `torque_bounds` as
        `apply_torques` clamps them: `apply_torques` without its clamp and checks."""
        list(map(_ADD_TORQUE, self.hinges, tau))

    def add_force(self, b: int, fx: float, fy: float = 0.0) -> None:
        """An external force (N) at body b's CoM for the next step."""
        self.bodies[b].addForce((fx, fy, 0.0))

    # ---- run-time joints ---------------------------------------------------------------
    def attach_prop(self, prop: str, body: str) -> ode.FixedJoint:
        """Weld prop `prop` to character body `body` in their present relative pose (a catch).
        The joint holds until `detach_all()` or the next `reset()`."""
        return self.join(prop, body)

    def join(self, prop: str, other: str,
             anchor: tuple[float, float] | None = None) -> ode.FixedJoint | ode.HingeJoint:
        """A joint made now between prop `prop` and `other` (a character body or another
        prop): a weld in their present relative pose (`anchor` None) or a z-axis hinge at the
        world point `anchor` (m), e.g. a chain's links. It holds until `detach_all()` or the
        next `reset()`. A joined prop's own Plane2DJoint is switched off: the joints keep it in
        the plane, which holds as long as the group it joins reaches the character or a
        hanging prop (the character's root has its planar joint)."""
        p = self.prop(prop)
        if other in self._body_index:
            b, q = self.bodies[self._body_index[other]], None
        elif other in self._prop_by_name and other != prop:
            q = self._prop_by_name[other]
            b = q.body
        else:
            raise SimError(f"unknown body {other!r}")
        if anchor is None:
            j = ode.FixedJoint(self.world)
            j.attach(p.body, b)
            j.setFixed()
        else:
            j = ode.HingeJoint(self.world)
            j.attach(p.body, b)
            j.setAnchor((float(anchor[0]), float(anchor[1]), 0.0))
            j.setAxis((0.0, 0.0, 1.0))
        j.setFeedback(True)
        self.attachments.append((j, prop, other))
        self._set_collide_bits()
        for joined in (p, q):
            if joined is not None:
                joined.plane.attach(None, None)  # the joints keep it in the plane now
        return j

    def attached(self, prop: str) -> bool:
        return any(name == prop for _j, name, _b in self.attachments)

    def detach_all(self) -> None:
        """Drop every run-time joint (feedback off first: PyODE trap 1)."""
        for j, prop, other in self.attachments:
            j.setFeedback(False)
            j.attach(None, None)
            for name in (prop, other):
                p = self._prop_by_name.get(name)
                if p is not None and p.definition.hanging is None:
                    p.plane.attach(p.body, ode.environment)
        if self.attachments:
            self.attachments.clear()
            self._set_collide_bits()

    # ---- contacts ------------------------------------------------------------------------
    def make_contacts(self, points: np.ndarray, feet_of_points: list[int]) -> None:
        """Ground contacts at the given world points (k, 2) of the given foot bodies."""
        c = self._contact
        for (px, py), b in zip(points.tolist(), feet_of_points, strict=True):
            if py > CONTACT_MARGIN:
                continue
            c.setContactGeomParams((px, py, 0.0), (0.0, 1.0, 0.0), -py)
            j = ode.ContactJoint(self.world, self.contact_group, c)
            j.attach(self.bodies[b], ode.environment)
            j.setFeedback(True)
            self.contacts.append((j, b, px))

    def _near(self, _arg: object, g1: ode.GeomObject, g2: ode.GeomObject) -> None:
        b1, b2 = g1.getBody(), g2.getBody()
        if b1 is not None and b2 is not None and ode.areConnected(b1, b2):
            return
        found = ode.collide(g1, g2)
        if not found:
            return
        n1, n2 = self._geom_owner[id(g1)], self._geom_owner[id(g2)]
        if n1 not in self._prop_by_name:  # the prop first: forces are reported on it
            g1, g2, b1, b2, n1, n2 = g2, g1, b2, b1, n2, n1
            flip = True
        else:
            flip = False
        if n2 == "ground":
            kind, other = PROP_GROUND, None
        elif n2 in self._prop_by_name:
            kind, other = PROP_PROP, n2
        else:
            kind, other = PROP_CHARACTER, n2
        mu = self._prop_by_name[n1].definition.friction
        bounce = self._prop_by_name[n1].definition.restitution
        if other in self._prop_by_name:
            mu = min(mu, self._prop_by_name[other].definition.friction)
            bounce = max(bounce, self._prop_by_name[other].definition.restitution)
        c = self._prop_contact if bounce == 0.0 else self._bouncing_contact(bounce)
        c.setMu(mu)
        for con in found:
            pos, normal, depth, _ga, _gb = con.getContactGeomParams()
            if pos[2] < -1e-9:
                continue  # the mirrored half of a box's contacts (trap 5)
            if flip:
                normal = (-normal[0], -normal[1], -normal[2])
            nx, ny = normal[0], normal[1]
            norm = math.hypot(nx, ny)
            if norm < 1e-9:
                continue
            nx, ny = nx / norm, ny / norm
            c.setContactGeomParams((pos[0], pos[1], 0.0), (nx, ny, 0.0), depth, g1, g2)
            c.setFDir1((-ny, nx, 0.0))
            j = ode.ContactJoint(self.world, self.prop_group, c)
            j.attach(b1, b2 if b2 is not None else ode.environment)
            j.setFeedback(True)
            self.prop_contacts.append((j, kind, n1, other, (pos[0], pos[1])))

    def _bouncing_contact(self, restitution: float) -> ode.Contact:
        """The contact of a prop with a restitution: rigid, with ODE's bounce (a separate
        object per restitution: plastic contacts stay as they were, bit for bit). Its CFM is
        BOUNCE_CFM, not the soft ground CFM: a soft contact's damping absorbs the rebound (a
        32 kg disc dropped 1.15 m with e = 0.9 rebounded to 1 % of its height with 7e-5), and
        even the world's 1e-6 let the impact impulse sink into the constraint (0.707 of the
        height for e^2 = 0.81; 0.809 with 1e-8; docs/physics.md, "Restitution")."""
        c = self._bounce_contacts.get(restitution)
        if c is None:
            c = ode.Contact()
            c.setMode(ode.ContactApprox1 | ode.ContactSoftCFM | ode.ContactMu2
                      | ode.ContactFDir1 | ode.ContactBounce)
            c.setMu2(0.0)
            c.setSoftCFM(BOUNCE_CFM)
            c.setBounce(restitution)
            c.setBounceVel(BOUNCE_MIN_SPEED)
            self._bounce_contacts[restitution] = c
        return c

    def collide_props(self) -> None:
        """Contact joints for every prop touching the ground, a prop or a character geom."""
        if self.props:
            self.space.collide(None, self._near)

    def step(self) -> None:
        """One DT step of the world; free props are re-projected onto the plane after it."""
        self.world.step(DT)
        if self.props:
            for p in self.props:
                if p.free:
                    p.reproject()

    def contact_forces(self) -> tuple[float, float, float]:
        """After a step: total normal force, total tangential force (N) of the feet's ground
        contacts and their CoP x (NaN without contact), from the contact joints' feedback
        (force on the body in f1)."""
        fy_sum = fx_sum = mx = 0.0
        for j, _b, px in self.contacts:
            f1 = j.getFeedback()[0]
            fy_sum += f1[1]
            fx_sum += f1[0]
            mx += f1[1] * px
        cop = mx / fy_sum if fy_sum > 1e-6 else math.nan
        return fy_sum, fx_sum, cop

    def contact_list(self) -> list[ContactForce]:
        """After a step: every contact with its force on the first body (feet and props)."""
        names = self.character.body_names
        return [ContactForce(FOOT_GROUND, names[b], None, (px, 0.0),
                             tuple(j.getFeedback()[0][:2])) for j, b, px in self.contacts
                ] + self.prop_contact_list()

    def prop_contact_list(self) -> list[ContactForce]:
        """`contact_list` without the feet's ground contacts (its tail): for a per-step
        look at the props' contacts that need not build the feet's."""
        return [ContactForce(kind, a, b, pos, tuple(j.getFeedback()[0][:2]))
                for j, kind, a, b, pos in self.prop_contacts]

    def clear_contacts(self) -> None:
        for j, _b, _px in self.contacts:
            j.setFeedback(False)
        self.contacts.clear()
        self.contact_group.empty()
        if self.prop_contacts:
            for j, *_rest in self.prop_contacts:
                j.setFeedback(False)
            self.prop_contacts.clear()
            self.prop_group.empty()

    def close(self) -> None:
        """Release every joint with feedback safely (feedback off before it is dropped)."""
        self.clear_contacts()
        self.detach_all()
        for p in self.props:
            p.close()
