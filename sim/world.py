"""The ODE world of a planar character: bodies, z-axis hinges, ground contacts, reset.

Choices, with the PyODE traps they avoid (see physics-notes):
- `world.step` (dense LCP), not `quickStep`: quickStep's ground force was 0.3-2 % off, and the
  balance objective is a ground-force measurement.
- World CFM is tiny (1e-6) so hinges stay rigid; ground contacts get the paper's soft CFM 7e-5
  through `ContactSoftCFM`, `ContactApprox1` so that mu = 1 is a friction coefficient, bounce 0.
- The ground is the plane y = 0. Contacts are made directly at each foot's heel and toe points
  (one per edge) instead of colliding boxes: 2 contacts per foot, none redundant.
- Hinges are attached (child, parent): ODE's angle is body1 minus body2, so `getAngle()` is the
  child's angle relative to the parent (counter-clockwise positive) and `addTorque(t)` puts +t on
  the child and -t on the parent. Axes are set in the zero pose, so ODE's zero is the model's.
- Contact joints live in a JointGroup; feedback is switched off on each before `empty()`
  (feedback + empty() aborts the process).
- One Plane2DJoint on the root keeps the chain in the plane.
"""

from __future__ import annotations

import math

import numpy as np
import ode

from sim.character import ROOT_DOF, Character
from sim.dynamics import GRAVITY, ModelArrays, forward_kinematics

DT = 0.001  # s, simulation step
WORLD_CFM = 1e-6
WORLD_ERP = 0.2
CONTACT_SOFT_CFM = 7e-5
FRICTION_MU = 1.0
CONTACT_MARGIN = 0.0005  # m: a heel/toe within this height of the ground gets a contact
TORQUE_LIMIT = 2000.0  # N m


class World:
    """One character in an ODE world. Build once; `reset(q, qd)` puts it in any state."""

    def __init__(self, character: Character, arrays: ModelArrays | None = None):
        self.character = character
        self.arrays = arrays or ModelArrays.from_character(character)
        self.world = ode.World()
        self.world.setGravity((0.0, -GRAVITY, 0.0))
        self.world.setERP(WORLD_ERP)
        self.world.setCFM(WORLD_CFM)
        ch = character
        self.bodies: list[ode.Body] = []
        for b in range(ch.n_bodies):
            body = ode.Body(self.world)
            mass = ode.Mass()
            i = float(ch.inertia[b])
            mass.setParameters(float(ch.mass[b]), 0.0, 0.0, 0.0, i, i, i, 0.0, 0.0, 0.0)
            body.setMass(mass)
            body.setPosition((float(ch.com0[b, 0]), float(ch.com0[b, 1]), 0.0))
            self.bodies.append(body)
        self.hinges: list[ode.HingeJoint] = []
        for b in range(1, ch.n_bodies):
            j = ode.HingeJoint(self.world)
            j.attach(self.bodies[b], self.bodies[ch.parent[b]])
            j.setAnchor((float(ch.anchor0[b, 0]), float(ch.anchor0[b, 1]), 0.0))
            j.setAxis((0.0, 0.0, 1.0))
            lo, hi = ch.limits[b - 1]
            j.setParam(ode.ParamLoStop, float(lo))
            j.setParam(ode.ParamHiStop, float(hi))
            self.hinges.append(j)
        self.plane = ode.Plane2DJoint(self.world)
        self.plane.attach(self.bodies[0], ode.environment)
        self.contact_group = ode.JointGroup()
        self.contacts: list[tuple[ode.ContactJoint, int, float]] = []
        self._contact = ode.Contact()
        # Friction only along x (ContactFDir1 with mu2 = 0 drops the out-of-plane friction
        # row, which the planar root constraint makes redundant).
        self._contact.setMode(
            ode.ContactApprox1 | ode.ContactSoftCFM | ode.ContactMu2 | ode.ContactFDir1)
        self._contact.setMu(FRICTION_MU)
        self._contact.setMu2(0.0)
        self._contact.setFDir1((1.0, 0.0, 0.0))
        self._contact.setBounce(0.0)
        self._contact.setSoftCFM(CONTACT_SOFT_CFM)
        self.q = np.zeros(ch.ndof)
        self.qd = np.zeros(ch.ndof)

    # ---- state ------------------------------------------------------------------------
    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Put every body in the state (q, qd) without rebuilding the world."""
        self.clear_contacts()
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
        self.read_state()

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Read q, qd from ODE: root CoM, root angle, then hinge angles and rates."""
        root = self.bodies[0]
        x, y, _ = root.getPosition()
        R = root.getRotation()
        vx, vy, _ = root.getLinearVel()
        q, qd = self.q, self.qd
        q[0], q[1], q[2] = x, y, math.atan2(R[3], R[0])
        qd[0], qd[1], qd[2] = vx, vy, root.getAngularVel()[2]
        for i, j in enumerate(self.hinges):
            q[ROOT_DOF + i] = j.getAngle()
            qd[ROOT_DOF + i] = j.getAngleRate()
        return q, qd

    def body_state(self, b: int) -> tuple[float, float, float]:
        """(x, y, angle) of body b's CoM as ODE has it."""
        body = self.bodies[b]
        x, y, _ = body.getPosition()
        R = body.getRotation()
        return x, y, math.atan2(R[3], R[0])

    # ---- actuation and contacts ---------------------------------------------------------
    def apply_torques(self, tau: np.ndarray) -> None:
        """Hinge torques (N m, +t on the child), clamped to +-TORQUE_LIMIT."""
        lim = TORQUE_LIMIT
        # Python min/max on the listed floats: the same clamp as np.clip, without its ~9 us
        # per-step call overhead (this runs every 1 ms step).
        for j, t in zip(self.hinges, tau.tolist(), strict=True):
            j.addTorque(min(max(t, -lim), lim))

    def add_force(self, b: int, fx: float, fy: float = 0.0) -> None:
        """An external force (N) at body b's CoM for the next step."""
        self.bodies[b].addForce((fx, fy, 0.0))

    def make_contacts(self, points: np.ndarray, feet_of_points: np.ndarray) -> None:
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

    def contact_forces(self) -> tuple[float, float, float]:
        """After a step: total normal force, total tangential force (N) and the CoP x
        (NaN without contact), from the contact joints' feedback (force on the body in f1)."""
        fy_sum = fx_sum = mx = 0.0
        for j, _b, px in self.contacts:
            f1 = j.getFeedback()[0]
            fy_sum += f1[1]
            fx_sum += f1[0]
            mx += f1[1] * px
        cop = mx / fy_sum if fy_sum > 1e-6 else math.nan
        return fy_sum, fx_sum, cop

    def clear_contacts(self) -> None:
        for j, _b, _px in self.contacts:
            j.setFeedback(False)
        self.contacts.clear()
        self.contact_group.empty()

    def step(self) -> None:
        self.world.step(DT)

    def close(self) -> None:
        """Release the contact joints safely (feedback off before the group is emptied)."""
        self.clear_contacts()
