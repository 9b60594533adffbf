"""PD servos: parent-space (joint angle) PD and the world-space ("inertial") PD of Jenkins,
Wrotek and McGuire, "Dynamic humanoid balance through inertial control" (planar here).

Both track the task's reference pose trajectory (the standing pose changed by the task's
motions) with one torque per hinge (N m, +t on the child, hinge order of the character):

* parent space (`pd_parent`), the paper's eq. 1 per hinge j:
      u_j = K1_j (theta_d,j - theta_j) + K2_j (thetadot_d,j - thetadot_j)
  with theta the hinge angle (child relative to parent) and thetadot_d the reference's
  analytic rate.

* world space (`pd_world`): every segment b is servoed toward its desired *world* angle W_d,b,
  lifted from the desired hinge angles through the desired chain from the root,
      W_d,b = W_d,root + sum of theta_d over the hinges from the root to b,
  so the actual angles of the other segments are ignored (the paper's key point); the desired
  angular velocity looks ahead by delta (eq. 2), omega_d = (W_d(t + delta) - W_d(t)) / delta,
  and the servo's world torque on segment b (eq. 3),
      tau_b = K1 (W_d,b - W_a,b) + K2 (omega_d,b - omega_a,b),
  is applied as in the paper: at b's own hinge, +tau_b on b and -tau_b on its parent, i.e.
  u_j = tau_(child of j). The root has no hinge. With `root: absolute` its world torque
  tau_root (toward the standing root angle) is what the paper applied as an external torque
  (the "super-balancing" it notes); here it is, as the paper proposes, propagated to the feet:
  every hinge on the path from the root to each of the n_f feet adds -tau_root / n_f, which
  gives the root +tau_root and leaves every other leg segment's net torque unchanged, the
  ground supplying -tau_root through the soles (so the CoP limits it, no external help).
  With `root: person` (the paper's egocentric "person space") the desired chain starts at
  the root's *actual* angle and angular velocity and the root gets no torque: its orientation
  is left free.

Gains: K1_j = k1 I_j and K2_j = k2 I_j, I_j (kg m^2) being the moment of inertia, about hinge
j in the zero pose, of what the hinge carries: the segments beyond it away from the feet (a
hinge whose child side holds no foot carries its child side; a hinge on a leg carries the
rest of the body, shared among the n_f feet). The root's world servo uses I_root, the inertia
of every segment but the feet about the ankles' midpoint. k1 (s^-2) and k2 (s^-1) are thus a
squared natural frequency and a damping rate common to every joint. Defaults: k1 = 100 s^-2
(10 rad/s, the momentum controller's joint tracking k_t; the standing body's gravity
stiffness about the ankles is only m g h / I ~ g / h ~ 10 s^-2) and k2 = 10 s^-1 (damping
ratio 0.5), the largest k2 at which the parent-space servo stands (docs/physics.md). Both
servos use the same table of gains, as in the paper's test of world space with the
parent-space gains.

Numerics: ODE applies hinge torques explicitly, and at these gains the explicit law diverges
in stance within 25-40 ms (closed-chain modes of the near-straight legs with little effective
inertia). So the law is evaluated at the next step's state (stable PD, Tan, Liu and Turk
2011): position error at q + dt qd, velocity error at qd + dt qdd, with qdd predicted by the
planar model with the feet held (the M, h, J_s the momentum controller uses); `stable: false`
gives the plain explicit law. The feet's own angular velocity is not fed back (a planted foot
has the ground as reference; fed back, a 1 kg foot's hinge damping chatters on its soft
contact).

Desired posture and the CMRT: the reference posture at t (the task's hinge targets, the
standing root angle) is leaned about the ankles' midpoint by the angle lambda(t) that puts its
CM over the support centre plus the CMRT's horizontal displacement d(t), the way the standing
pose itself is found (`balance: true` in the character file); without a CMRT d = 0, the
momentum controller's CM reference. The feet's hinges' targets get +lambda (the body above
them turns forward by lambda while the feet stay flat); in world space with an absolute root
the root's desired angle gets -lambda too, so every desired world angle above the feet turns
by -lambda and the feet's stay flat. A servo with no CM term of its own thus tracks the CMRT
through its posture. Balance is lost (`lost`) when a heel or toe lifts FOOT_LIFT_LIMIT, the
momentum controller's foot rule.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.controllers.base import Cmrt, Controller, Observation
from sim.controllers.config import ControllerConfig, ControllerContext
from sim.controllers.momentum import FOOT_LIFT_LIMIT
from sim.dynamics import ModelArrays, forward_kinematics
from sim.errors import SimError
from sim.linalg import matvec, solve, tmatvec
from sim.specbase import quantity
from sim.trajectory import PoseTrajectory

#: Default position gain (s^-2): torque per radian per kg m^2 carried (10 rad/s squared).
DEFAULT_K1 = 100.0
#: Default velocity gain (s^-1): damping ratio 0.5 at k1; the largest of 5, 10, 20, 40 at
#: which the parent-space servo stands (docs/physics.md, "PD servos").
DEFAULT_K2 = 10.0
#: Default look-ahead (s) of the desired angular velocity: the paper takes the time between
#: motion-capture frames; the CMU database it drew on records at 120 Hz.
DEFAULT_DELTA = 1.0 / 120.0
CMRT_VELOCITY_STEP = 1e-3  # s, central difference of the lean for the parent-space rate
#: Regularisation of the feet-held model's KKT system (straight knees drop a rank of J_s),
#: the momentum controller's value.
CONSTRAINT_REGULARISATION = 1e-7


def _subtree(parent: np.ndarray, b: int) -> set[int]:
    """Body b and every body below it."""
    out = {b}
    for k in range(b + 1, parent.shape[0]):  # parents are listed before children
        if int(parent[k]) in out:
            out.add(k)
    return out


def _inertia_about(ch: Character, bodies: set[int] | list[int], point: np.ndarray) -> float:
    """Moment of inertia (kg m^2) of `bodies` about `point`, zero pose."""
    idx = sorted(bodies)
    r = ch.com0[idx] - point
    return float((ch.inertia[idx] + ch.mass[idx] * (r ** 2).sum(axis=1)).sum())


def carried_inertia(ch: Character) -> tuple[np.ndarray, float]:
    """(I_j per hinge, I_root) in kg m^2, zero pose: what each hinge carries (see the module
    docstring) and the whole body but the feet about the ankles' midpoint."""
    nb = ch.n_bodies
    feet = {int(f) for f in ch.feet}
    everything = set(range(nb))
    inertia = np.zeros(ch.n_hinges)
    for j in range(ch.n_hinges):
        child = j + 1
        side = _subtree(ch.parent, child)
        anchor = ch.anchor0[child]
        if side & feet:
            inertia[j] = _inertia_about(ch, everything - side, anchor) / len(feet)
        else:
            inertia[j] = _inertia_about(ch, side, anchor)
    ankles = ch.anchor0[sorted(feet)].mean(axis=0)
    root = _inertia_about(ch, everything - feet, ankles)
    return inertia, root


def support_offset(ch: Character) -> float:
    """Support centre x minus the ankles' midpoint x (m), zero pose (feet flat)."""
    centre = 0.5 * (ch.heel0[:, 0].min() + ch.toe0[:, 0].max())
    return float(centre - ch.anchor0[ch.feet, 0].mean())


class PdServo(Controller):
    """Parent-space or world-space PD on every hinge (the Controller protocol); see the module
    docstring for the laws, the gains and how the CMRT enters."""

    def __init__(self, character: Character, arrays: ModelArrays, trajectory: PoseTrajectory,
                 standing: np.ndarray,
                 space: str, k1: float = DEFAULT_K1, k2: float = DEFAULT_K2,
                 delta: float = DEFAULT_DELTA, root: str = "absolute", dt: float = 0.001,
                 stable: bool = True):
        if space not in ("parent", "world"):
            raise ValueError(f"space must be 'parent' or 'world', got {space!r}")
        if root not in ("absolute", "person"):
            raise ValueError(f"root must be 'absolute' or 'person', got {root!r}")
        ch = character
        self.character = ch
        self.trajectory = trajectory
        self.space = space
        self.root = root
        self.delta = delta
        self.root_angle = float(standing[2])  # the root's desired world angle (absolute)
        inertia, root_inertia = carried_inertia(ch)
        self.K1, self.K2 = k1 * inertia, k2 * inertia
        self.dt = dt
        self.stable = stable
        self.K1_root, self.K2_root = k1 * root_inertia, k2 * root_inertia
        self.arrays = arrays
        self.support_offset = support_offset(ch)
        self.masses = ch.mass / ch.mass.sum()
        nb = ch.n_bodies
        self.parent = ch.parent.astype(int).tolist()
        # hinge j moves body j + 1; ankle hinges are the feet's own; the root's torque goes
        # to every hinge on a root-foot path, 1 / n_f each.
        self.ankles = [int(f) - 1 for f in ch.feet]
        self.feet = [int(f) for f in ch.feet]
        spread = np.zeros(ch.n_hinges)
        for f in ch.feet:
            b = int(f)
            while b > 0:
                spread[b - 1] -= 1.0 / len(ch.feet)
                b = self.parent[b]
        self.root_spread = spread
        # chain[b]: the hinges from the root to body b (lift = root angle + their sum)
        self.lift_matrix = np.zeros((nb, ch.n_hinges))
        for b in range(1, nb):
            k = b
            while k > 0:
                self.lift_matrix[b, k - 1] = 1.0
                k = self.parent[k]
        # The laws' derivatives, constant (n_h, n) matrices: d tau / d q = -B_p (position
        # gains), d tau / d qd = -B_d (velocity gains); the stable PD needs both.
        n = ch.ndof
        self.B_p, self.B_d = np.zeros((ch.n_hinges, n)), np.zeros((ch.n_hinges, n))
        if space == "parent":
            hinges = np.arange(ch.n_hinges)
            self.B_p[hinges, ROOT_DOF + hinges] = self.K1
            self.B_d[hinges, ROOT_DOF + hinges] = self.K2
        else:
            rows = np.zeros((nb, n))  # world angle of each body as a function of q
            rows[:, 2] = 1.0 if root == "absolute" else 0.0  # person: relative to the root
            rows[:, ROOT_DOF:] = self.lift_matrix
            self.B_p = self.K1[:, None] * rows[1:]
            self.B_d = self.K2[:, None] * rows[1:]
            if root == "absolute":
                self.B_p += np.outer(spread, self.K1_root * rows[0])
                self.B_d += np.outer(spread, self.K2_root * rows[0])
        # The feet are planted: their measured angular velocity is not fed back (the ground is
        # their reference). A foot weighs ~1 kg: fed back, its hinge's damping (360 N m s/rad
        # at the defaults) times dt / (its 0.018 kg m^2) is ~20, and the explicit torque makes
        # the foot chatter on its soft contact and diverge within tens of ms.
        self.foot_rows = np.zeros((len(self.ankles), n))
        for i, f in enumerate(ch.feet):
            self.foot_rows[i, 2] = 1.0
            self.foot_rows[i, ROOT_DOF:] = self.lift_matrix[int(f)]
        self.B_d[self.ankles] -= self.K2[self.ankles, None] * self.foot_rows
        self.reference: Cmrt | None = None
        self.lost: str | None = None
        self.c_ref: tuple[float, float] = (0.0, 0.0)

    # ---- the Controller protocol ----------------------------------------------------------
    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None:
        self.reference = reference
        self.lost = None
        self.c_ref = (0.0, 0.0)

    def act(self, obs: Observation, t: float) -> np.ndarray:
        """Hinge torques for this step; sets `lost` when a heel or toe has lifted."""
        lo, hi = obs.support
        disp = self.displacement(t)
        self.c_ref = (0.5 * (lo + hi) + disp, 0.0)
        if self.space == "parent":
            tau = self.parent_torques(obs.q, obs.qd, t)
        else:
            tau = self.world_torques(obs.q, obs.qd, t)
        tau[self.ankles] += self.K2[self.ankles] * matvec(self.foot_rows, obs.qd)  # feet planted
        if self.stable:
            tau = self.stable_torques(tau, obs)
        if max(obs.points[:, 1].tolist()) > FOOT_LIFT_LIMIT:
            self.lost = "foot_lift"
        return tau

    def stable_torques(self, tau: np.ndarray, obs: Observation) -> np.ndarray:
        """The law evaluated at the next step's state (stable PD, Tan, Liu and Turk 2011):
        position error at q + dt qd, velocity error at qd + dt qdd, qdd predicted by the
        planar model with the feet held (M qdd + h = S^T tau + J_s^T f, J_s qdd = 0):
        tau = tau_explicit - dt (B_p qd + B_d qdd), the damping solved implicitly."""
        dt, n = self.dt, self.character.ndof
        tau0 = tau - dt * matvec(self.B_p, obs.qd)
        js = obs.Js
        k = js.shape[0]
        K = np.zeros((n + k, n + k))
        K[:n, :n] = obs.M
        K[ROOT_DOF:n, :n] += dt * self.B_d
        K[:n, n:] = -js.T
        K[n:, :n] = js
        K[n:, n:] = CONSTRAINT_REGULARISATION * np.eye(k)
        rhs = np.zeros(n + k)
        rhs[:n] = -obs.h
        rhs[ROOT_DOF:n] += tau0
        try:
            qdd = solve(K, rhs)[:n]
        except np.linalg.LinAlgError:
            raise SimError("the PD servo's feet-held model is singular at this state (gains "
                           f"k2 {self.K2.max():.3g} N m s/rad at most)") from None
        return tau0 - dt * matvec(self.B_d, qdd)

    # ---- the laws -------------------------------------------------------------------------
    def displacement(self, t: float) -> float:
        """The CMRT's horizontal displacement (m) at t; 0 without a CMRT."""
        if self.reference is None:
            return 0.0
        v = self.reference(t)
        return float(v[0]) if isinstance(v, tuple | list | np.ndarray) else float(v)

    def lean(self, t: float) -> float:
        """The desired lean (rad, forward positive) about the ankles' midpoint that puts the
        CM of the reference posture at t (the task's hinge targets, the standing root angle)
        over the support centre plus the CMRT's displacement."""
        q = np.zeros(self.character.ndof)
        q[2] = self.root_angle
        q[ROOT_DOF:] = self.trajectory(t)[0]
        a = self.arrays
        _, p, o = forward_kinematics(q, a.parent, a.a_par, a.a_chi)
        v = tmatvec(p, self.masses) - o[self.feet].mean(axis=0)  # CM from the ankles
        radius = math.hypot(v[0], v[1])
        target = self.support_offset + self.displacement(t)
        return math.asin(min(max(target / radius, -1.0), 1.0)) - math.atan2(v[0], v[1])

    def desired_hinges(self, t: float, rates: bool = False,
                       ) -> tuple[np.ndarray, np.ndarray, float]:
        """(desired hinge angles with the lean at the ankles, their rates (with `rates`; the
        lean's by a central difference), lean)."""
        q_r, qd_r, _ = self.trajectory(t)
        lam = self.lean(t)
        q_r = q_r.copy()
        q_r[self.ankles] += lam
        if rates:
            h = CMRT_VELOCITY_STEP
            rate = (self.lean(t + h) - self.lean(t - h)) / (2.0 * h)
            qd_r = qd_r.copy()
            qd_r[self.ankles] += rate
        return q_r, qd_r, lam

    def parent_torques(self, q: np.ndarray, qd: np.ndarray, t: float) -> np.ndarray:
        """Eq. 1 per hinge: K1 (theta_d - theta) + K2 (thetadot_d - thetadot)."""
        th_d, thd_d, _ = self.desired_hinges(t, rates=True)
        return self.K1 * (th_d - q[ROOT_DOF:]) + self.K2 * (thd_d - qd[ROOT_DOF:])

    def desired_world(self, t: float, root_angle: float | None = None) -> np.ndarray:
        """W_d per body (rad): the desired hinge angles lifted through the desired chain from
        the root, whose angle is `root_angle` (person space) or, by default, the standing
        root angle minus the lean (absolute)."""
        th_d, _, lam = self.desired_hinges(t)
        root = self.root_angle - lam if root_angle is None else root_angle
        return root + matvec(self.lift_matrix, th_d)

    def world_torques(self, q: np.ndarray, qd: np.ndarray, t: float) -> np.ndarray:
        """Eqs. 2-3 per segment, applied at each segment's own hinge; the root's (absolute)
        propagated to the feet (module docstring)."""
        hinge_q, hinge_qd = q[ROOT_DOF:], qd[ROOT_DOF:]
        w_a = q[2] + matvec(self.lift_matrix, hinge_q)
        om_a = qd[2] + matvec(self.lift_matrix, hinge_qd)
        d = self.delta
        if self.root == "person":
            # the desired chain from the actual root; the root's own motion is not fought
            w_now = self.desired_world(t, 0.0)
            w_next = self.desired_world(t + d, 0.0)
            w_d = q[2] + w_now
            om_d = qd[2] + (w_next - w_now) / d
        else:
            w_d = self.desired_world(t)
            om_d = (self.desired_world(t + d) - w_d) / d
        err, derr = w_d - w_a, om_d - om_a
        tau = self.K1 * err[1:] + self.K2 * derr[1:]
        if self.root == "absolute":
            tau_root = self.K1_root * err[0] + self.K2_root * derr[0]
            tau = tau + tau_root * self.root_spread
        return tau


class PdConfig(ControllerConfig):
    """The gains shared by both PD servos (see sim.controllers.pd)."""

    #: Position gain (s^-2) per kg m^2 a hinge carries.
    k1: quantity(0.001, 1e4, "s^-2 per kg m^2") = DEFAULT_K1
    #: Velocity gain (s^-1) per kg m^2 a hinge carries.
    k2: quantity(0.001, 1e3, "s^-1 per kg m^2") = DEFAULT_K2
    #: Evaluate the law at the predicted next-step state (stable PD); false: the plain
    #: explicit law, which ODE's explicit torques make diverge at the default gains.
    stable: bool = True

    space: ClassVar[str] = "parent"

    def check(self, spec: Any, character: Character) -> None:
        if spec.cmrt.vertical:
            raise ValueError(f"cmrt.vertical: the {self.type} servo follows a horizontal "
                             "CMRT only (a lean about the ankles); set it false")

    def _servo(self, context: ControllerContext, **kw: Any) -> Controller:
        return PdServo(context.character, context.arrays, context.trajectory, context.standing,
                       self.space,
                       k1=self.k1, k2=self.k2, dt=context.dt, stable=self.stable, **kw)


class PdParentConfig(PdConfig):
    """`controller: {type: pd_parent, k1?, k2?}`: parent-space PD on every hinge."""

    type: Literal["pd_parent"]

    def build(self, context: ControllerContext) -> Controller:
        return self._servo(context)


class PdWorldConfig(PdConfig):
    """`controller: {type: pd_world, k1?, k2?, delta?, root?}`: the world-space (inertial)
    PD; `delta` (s) is the look-ahead of the desired angular velocity (eq. 2), `root` the
    root's servo: `absolute` (toward the standing root angle, propagated to the feet) or
    `person` (egocentric: the root left free)."""

    type: Literal["pd_world"]
    delta: quantity(0.001, 0.5, "s") = DEFAULT_DELTA
    root: Literal["absolute", "person"] = "absolute"

    space: ClassVar[str] = "world"

    def build(self, context: ControllerContext) -> Controller:
        return self._servo(context, delta=self.delta, root=self.root)
