"""The momentum balance controller (Macchietto et al. 2009, as in the paper's section 3).

At QP_RATE (60 Hz) it chooses joint accelerations qdd* minimising

    b_l |Ldot_des - A_L qdd|^2 + b_h |Hdot_des - A_H qdd|^2 + b_t |W (qdd_des - qdd)|^2
    subject to J_s qdd = 0                                   (the feet stay planted)

through the KKT system (momentum rows divided by the total mass so the weights are comparable;
J-dot terms ignored, as in the paper). Every simulation step, floating-base inverse dynamics
turns qdd* into hinge torques with the root unactuated (`sim.dynamics.inverse_dynamics`). When
the support wrench leaves the friction cone or its centre of pressure leaves the support, the
controller has lost balance and hands over to the fall controller: a low-stiffness critically
damped PD on the last pose.

Linear momentum: Ldot_des,x = k_l m (c_r,x - c_x) + d_l (m cdot_r,x - L_x), with
c_r = support centre + CMRT displacement; vertically damping only, Ldot_des,y = -d_lv L_y,
since a bend lowers the CM and a fixed height target would fight the pose. A CMRT's vertical
part dy enters as a posture (`sim.controllers.crouch`): the legs' reference angles bend so that
the reference posture's CM is dy lower, and the vertical damping is toward the CMRT's vertical
rate, Ldot_des,y = d_lv (m dy' - L_y). (A vertical CM target in the momentum objective alone
moves the CM a few per cent of the way against the tracking term: docs/physics.md.)
Angular momentum: the desired CoP is the support centre (kept COP_MARGIN inside the support)
and Hdot_des = (p_des - c_x) F_y + c_y F_x with F = Ldot_des - m g, the ground force that
places the CoP there.

Optional CoP objective (`b_p` > 0, scheduled into a task window, off by default as in the
paper): the QP then uses the velocity-product terms of the momentum rates and of the foot
constraint (`sim.dynamics.momentum_bias`; the paper ignores them) and adds
b_p |((c_x - s) F_y + Hdot - c_y F_x) / m|^2, i.e. the implied CoP's distance from the support
centre times the normal force. During a fast bend the trunk's centripetal reaction moves the
real CoP by up to ~45 cm from what the plain QP predicts (docs/physics.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.controllers.base import Cmrt, Controller, Observation
from sim.controllers.crouch import RATE_STEP, Crouch
from sim.dynamics import (
    GRAVITY,
    WRENCH_NO_NORMAL_FORCE,
    WRENCH_OK,
    WRENCH_REASONS,
    ModelArrays,
    checked_inverse_dynamics_feet,
    checked_inverse_dynamics_lift,
    momentum_bias,
)
from sim.linalg import dot, gram, solve, tmatvec
from sim.trajectory import PoseTrajectory, ease

QP_RATE = 60.0  # Hz
COP_MARGIN = 0.02  # m, desired CoP kept this far inside the heel/toe edges
QDD_REGULARISATION = 1e-4  # on |qdd|^2: keeps the KKT matrix definite
CONSTRAINT_REGULARISATION = 1e-7  # straight knees in double support drop a rank of J_s
#: The controller has lost balance when its support wrench stays inadmissible this long (s)...
WRENCH_VIOLATION_LIMIT = 0.25
#: ... or when a heel or toe has lifted this high (m): the foot is rotating about an edge and
#: the foot-fixed model no longer holds.
FOOT_LIFT_LIMIT = 0.03
#: m: with the feet apart, each foot's own CoP is kept this far inside its heel and toe.
FOOT_COP_MARGIN = 0.01
CMRT_VELOCITY_STEP = 1e-3  # s, central difference for the CMRT's velocity


@dataclass(frozen=True)
class ControllerParams:
    """Gains and weights. Defaults balance the 70 kg humanoid (see docs/physics.md)."""

    k_l: float = 20.0  # s^-2, CM spring
    d_l: float = 7.0  # s^-1, CM damping (horizontal)
    d_l_vertical: float = 7.0  # s^-1, vertical momentum damping
    k_t: float = 100.0  # s^-2, joint tracking stiffness
    d_t: float = 20.0  # s^-1, joint tracking damping
    b_l: float = 1.0  # weight of the linear momentum objective
    b_h: float = 3.0  # weight of the angular momentum objective
    b_t: float = 0.1  # weight of the tracking objective
    #: Weight of the centre-of-pressure objective (0: off, the paper's controller). With it the
    #: QP predicts the momentum rates with their velocity-product terms and also minimises
    #: |(p - s) F_y / m|^2, the implied CoP's distance from the support centre s times the
    #: normal force (linear in qdd). Meant for a task window only (see docs/physics.md): held
    #: all the time it takes away the CM's feedback, which goes through the CoP.
    b_p: float = 0.0
    #: Hard CoP constraint (m; 0: off). With it > 0 the QP predicts the momentum rates with
    #: their velocity-product terms, as for b_p, and keeps the implied CoP at least this far
    #: inside the heel and toe edges (an inequality: inactive while the plan's CoP is inside,
    #: so it leaves the CM's feedback alone; see docs/physics.md).
    cop_box: float = 0.0
    #: Tracking weights W by joint name overriding the character file's (`joint.weight`).
    weights: dict[str, float] = field(default_factory=dict)

    def with_overrides(self, values: dict[str, float]) -> ControllerParams:
        names = {f.name for f in fields(self)} - {"weights"}
        bad = set(values) - names
        if bad:
            raise ValueError(f"unknown controller parameters: {sorted(bad)}")
        return replace(self, **values)

    def scaled(self, factors: dict[str, float]) -> ControllerParams:
        return replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})

    def weight_vector(self, character: Character) -> np.ndarray:
        """W per hinge: the character file's tracking weights, with `weights` overriding."""
        if not self.weights:
            return character.tracking_weights
        return np.array([self.weights.get(n, float(w)) for n, w in
                         zip(character.hinge_names, character.tracking_weights, strict=True)])


class GainScheduler:
    """Ease-in-ease-out changes of gains over time windows (paper 6.3.2).

    Each entry (start, end, ramp, factors[, targets]): inside [start, end] the named parameters
    are multiplied by 1 + (factor - 1) w(t), and those in `targets` move to
    value + (target - value) w(t), w rising from 0 to 1 over `ramp` after `start` and falling
    back to 0 over `ramp` before `end`.
    """

    def __init__(self, base: ControllerParams, entries: list[tuple]):
        self.base = base
        self.entries = [e if len(e) == 5 else (*e, {}) for e in entries]

    def __call__(self, t: float) -> ControllerParams:
        factors: dict[str, float] = {}
        moves: list[tuple[str, float, float]] = []
        for start, end, ramp, scale, targets in self.entries:
            if not start <= t <= end:
                continue
            r = max(min(ramp, 0.5 * (end - start)), 1e-9)
            w = min(ease((t - start) / r)[0], ease((end - t) / r)[0])
            for k, v in scale.items():
                factors[k] = factors.get(k, 1.0) * (1.0 + (v - 1.0) * w)
            moves += [(k, v, w) for k, v in targets.items()]
        if not factors and not moves:
            return self.base
        prm = self.base.scaled(factors)
        if moves:
            values = {k: getattr(prm, k) for k, _, _ in moves}
            for k, target, w in moves:
                values[k] += (target - values[k]) * w
            prm = replace(prm, **values)
        return prm


def stance_bias(a: ModelArrays, obs: Observation) -> tuple[np.ndarray, float, np.ndarray]:
    """`sim.dynamics.momentum_bias` at the observed state, its foot rows (b_S) those of the
    observation's stance feet only (a swing foot has no constraint)."""
    b_L, b_H, b_S = momentum_bias(obs.q, obs.qd, a.parent, a.a_par, a.a_chi, a.mass, a.feet,
                                  a.sole_local)
    if obs.stance is not None and len(obs.stance) != len(a.feet):
        b_S = b_S[[3 * f + r for f in obs.stance for r in range(3)]]
    return b_L, b_H, b_S


def _as_pair(value: object) -> tuple[float, float]:
    if isinstance(value, tuple | list | np.ndarray):
        return float(value[0]), float(value[1]) if len(value) > 1 else 0.0
    return float(value), 0.0


class MomentumController(Controller):
    """The momentum QP at `qp_rate` and inverse dynamics every step (the Controller protocol).

    Between QP solves it holds qdd*. Balance is lost (`lost` set) when the inverse dynamics'
    support wrench stays outside the friction cone `mu` or its CoP outside the support for
    WRENCH_VIOLATION_LIMIT, when it needs a pulling ground, or when a heel or toe lifts
    FOOT_LIFT_LIMIT: brief violations are tolerated (docs/physics.md, "When balance is lost").
    The reference is the CMRT: c_r = support centre + its displacement.
    """

    def __init__(self, character: Character, schedule: GainScheduler,
                 trajectory: PoseTrajectory, arrays: ModelArrays | None = None,
                 dt: float = 0.001, mu: float = 1.0, qp_rate: float = QP_RATE):
        self.character = character
        self.schedule = schedule
        self.trajectory = trajectory
        self.arrays = arrays or ModelArrays.from_character(character)
        self.dt = dt
        self.mu = mu
        self.qp_every = max(1, int(round(1.0 / (qp_rate * dt))))
        self.n = character.ndof
        self.mass = character.total_mass
        self.qdd = np.zeros(self.n)
        self.reference: Cmrt | None = None
        self.c_ref: tuple[float, float] = (0.0, 0.0)
        self.lost: str | None = None
        self._k = 0
        self._violation_steps = 0
        self._disp = (0.0, 0.0)
        #: The vertical CMRT's posture (built at its first use) and, while it is non-zero,
        #: its hinge offsets and their rates (rad, rad/s, rad/s^2) added to the reference.
        self._crouch: Crouch | None = None
        self._crouch_terms: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        #: True: the support wrench is shared between the stance feet by
        #: `sim.dynamics.inverse_dynamics_feet` (feet apart, after a step); False: the plain
        #: least-norm wrench (feet side by side, the default).
        self.feet_apart = False
        #: m: a stance heel or toe this high loses balance (FOOT_LIFT_LIMIT by default).
        self.foot_lift_limit = FOOT_LIFT_LIMIT
        # The QP's constant matrices, built once instead of at every solve (the same values).
        self._qdd_regularisation = QDD_REGULARISATION * np.eye(self.n)
        self._constraint_blocks: dict[int, np.ndarray] = {}
        self._tracking: tuple[ControllerParams, np.ndarray, np.ndarray] | None = None

    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None:
        self.qdd = np.zeros(self.n)
        self.reference = reference
        self.lost = None
        self._k = 0
        self._violation_steps = 0
        self._disp = (0.0, 0.0)
        self._crouch_terms = None
        self.c_ref = (0.0, 0.0)

    def act(self, obs: Observation, t: float) -> np.ndarray:
        """Hinge torques for this step; sets `lost` when the support wrench says so."""
        lo, hi = obs.support
        if self._k % self.qp_every == 0:
            vel = (0.0, 0.0)
            cmrt = self.reference
            if cmrt is not None:
                self._disp = _as_pair(cmrt(t))
                nxt = _as_pair(cmrt(t + CMRT_VELOCITY_STEP))
                prv = _as_pair(cmrt(t - CMRT_VELOCITY_STEP))
                vel = ((nxt[0] - prv[0]) / (2 * CMRT_VELOCITY_STEP),
                       (nxt[1] - prv[1]) / (2 * CMRT_VELOCITY_STEP))
                self._crouch_terms = (self._crouch_offsets(cmrt, t)
                                      if self._disp[1] or nxt[1] or prv[1] else None)
            s = 0.5 * (lo + hi)
            self.c_ref = (s + self._disp[0], self._disp[1])
            self.solve(t, obs.q, obs.qd, obs.c, obs.cd, obs.A_L, obs.A_H, obs.Js, (lo, hi),
                       self.c_ref, vel, lambda: stance_bias(self.arrays, obs))
        self._k += 1
        if self.feet_apart and len(obs.sole_x) > 1:
            tau, code, _cop = checked_inverse_dynamics_feet(
                obs.M, obs.h, obs.Js, self.qdd, obs.points, obs.sole_x, lo, hi, self.mu,
                FOOT_COP_MARGIN)
            top = max(obs.points[:, 1].tolist())
        else:
            # One compiled call for the wrench and the stance heels' and toes' highest point.
            tau, code, _cop, top = checked_inverse_dynamics_lift(
                obs.M, obs.h, obs.Js, self.qdd, obs.sole_x, obs.points, lo, hi, self.mu)
        self._judge(code, top)
        return tau

    def held_torque_step(self) -> bool:
        """Whether the next `act` holds qdd* (no QP solve) and shares the support wrench by
        least norm over every foot: its torques are then those of
        `sim.dynamics.step_model_held` with `qdd` and `mu`, and the rollout may compute them
        in that one compiled call with the model terms and report the wrench through
        `held_act` instead of calling `act` (the same torques and state, bit for bit)."""
        return self._k % self.qp_every != 0 and not self.feet_apart

    def held_act(self, code: int, top: float) -> None:
        """What `act` does after its inverse dynamics on a step `held_torque_step` allowed,
        given the wrench code and the highest stance heel or toe `step_model_held` found."""
        self._k += 1
        self._judge(code, top)

    def _judge(self, code: int, top: float) -> None:
        """Count the steps with an inadmissible wrench and set `lost` (see the class)."""
        violations = self._violation_steps + 1 if code != WRENCH_OK else 0
        self._violation_steps = violations
        if code == WRENCH_NO_NORMAL_FORCE or violations * self.dt > WRENCH_VIOLATION_LIMIT:
            self.lost = WRENCH_REASONS[code]
        elif top > self.foot_lift_limit:  # stance heels and toes
            self.lost = "foot_lift"

    def _crouch_offsets(self, cmrt: Cmrt, t: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The vertical CMRT's leg offsets at t and their rates (central differences over
        RATE_STEP), or None while the vertical displacement is zero around t."""
        h = RATE_STEP
        dys = [_as_pair(cmrt(u))[1] for u in (t - h, t, t + h)]
        if not any(dys):
            return None
        if self._crouch is None:
            self._crouch = Crouch(self.character, self.arrays)
        off = [self._crouch.offsets(self.trajectory(u)[0], dy)
               for u, dy in zip((t - h, t, t + h), dys, strict=True)]
        return off[1], (off[2] - off[0]) / (2 * h), (off[2] - 2 * off[1] + off[0]) / (h * h)

    def desired_rates(self, prm: ControllerParams, c: np.ndarray, cd: np.ndarray,
                      support: tuple[float, float], c_ref: tuple[float, float],
                      cd_ref: tuple[float, float]) -> tuple[np.ndarray, float]:
        """(Ldot_des (2,), Hdot_des about the CoM) for the gains `prm` (see the module doc)."""
        m = self.mass
        L = m * cd
        ldot = np.array([
            prm.k_l * m * (c_ref[0] - c[0]) + prm.d_l * (m * cd_ref[0] - L[0]),
            prm.d_l_vertical * (m * cd_ref[1] - L[1]),
        ])
        F = ldot + np.array([0.0, m * GRAVITY])
        lo, hi = support
        p_des = min(max(0.5 * (lo + hi), lo + COP_MARGIN), hi - COP_MARGIN)
        return ldot, (p_des - c[0]) * F[1] + c[1] * F[0]

    def solve(self, t: float, q: np.ndarray, qd: np.ndarray, c: np.ndarray, cd: np.ndarray,
              A_L: np.ndarray, A_H: np.ndarray, Js: np.ndarray, support: tuple[float, float],
              c_ref: tuple[float, float], cd_ref: tuple[float, float],
              bias: Callable[[], tuple[np.ndarray, float, np.ndarray]] | None = None,
              ) -> np.ndarray:
        """New qdd* from the state; support = (back edge x, front edge x), c_ref = (x, dy).

        `bias` returns (b_L, b_H, b_S) of `sim.dynamics.momentum_bias` for this state; it is
        called only when the scheduled b_p or cop_box is > 0 (and must then be given): the QP
        then predicts Ldot = A_L qdd + b_L, Hdot = A_H qdd + b_H, keeps the feet planted with
        J_s qdd = -b_S, and adds the CoP objective (b_p) and the CoP constraint (cop_box)."""
        prm = self.schedule(t)
        use_bias = prm.b_p > 0.0 or prm.cop_box > 0.0
        if use_bias and bias is None:
            raise ValueError("b_p > 0 or cop_box > 0 needs the velocity-product terms (bias)")
        m = self.mass
        n = self.n
        lo, hi = support
        centre = 0.5 * (lo + hi)
        ldot, hdot = self.desired_rates(prm, c, cd, support, c_ref, cd_ref)
        q_r, qd_r, qdd_r = self.trajectory(t)
        if self._crouch_terms is not None:
            q_r, qd_r, qdd_r = (a + b for a, b in zip((q_r, qd_r, qdd_r), self._crouch_terms,
                                                      strict=True))
        hq = slice(ROOT_DOF, n)
        qdd_des = prm.k_t * (q_r - q[hq]) + prm.d_t * (qd_r - qd[hq]) + qdd_r
        w2, tracking = self._tracking_terms(prm)
        Al = A_L / m
        ah = A_H / m
        # ah[:, None] * ah is np.outer's own product (its values), without its Python wrapper.
        H = prm.b_l * gram(Al) + prm.b_h * (ah[:, None] * ah)
        H[hq, hq] += tracking
        H += self._qdd_regularisation
        rhs_c = np.zeros(Js.shape[0])
        if use_bias:
            b_L, b_H, b_S = bias()
            ldot = ldot - b_L  # what A_L qdd must supply
            hdot = hdot - b_H
            rhs_c = -b_S
            # CoP objective: (p - s) F_y = (c_x - s) F_y + Hdot - c_y F_x, linear in qdd
            dx = c[0] - centre
            a_p = (dx * A_L[1] + A_H - c[1] * A_L[0]) / m
            r_p = (dx * (b_L[1] + m * GRAVITY) + b_H - c[1] * b_L[0]) / m
            if prm.b_p > 0.0:
                H += prm.b_p * np.outer(a_p, a_p)
        g = prm.b_l * tmatvec(Al, ldot / m) + prm.b_h * ah * (hdot / m)
        g[hq] += prm.b_t * w2 * qdd_des
        if use_bias:
            g -= prm.b_p * a_p * r_p
        extra = self.extra_objective()
        if extra is not None:
            H += extra[0]
            g += extra[1]
        k = Js.shape[0]
        K = np.zeros((n + k, n + k))
        K[:n, :n] = H
        K[:n, n:] = Js.T
        K[n:, :n] = Js
        K[n:, n:] = self._constraint_regularisation(k)
        rhs = np.concatenate([g, rhs_c])
        x = solve(K, rhs)
        if prm.cop_box > 0.0:
            x = self._keep_cop_inside(K, rhs, x, n, a_p, r_p, A_L[1] / m,
                                      (b_L[1] + m * GRAVITY) / m,
                                      (lo + prm.cop_box - centre, hi - prm.cop_box - centre))
        self.qdd = x[:n]
        return self.qdd

    def extra_objective(self) -> tuple[np.ndarray, np.ndarray] | None:
        """More quadratic terms of the QP, (H (n, n), g (n,)) added to its cost
        1/2 qdd^T H qdd - g^T qdd before it is solved (a stepping controller's task-space
        tracking of the swing); None (the default): none, the QP as the module doc says."""
        return None

    def _tracking_terms(self, prm: ControllerParams) -> tuple[np.ndarray, np.ndarray]:
        """(W^2, b_t diag(W^2)) for the gains `prm`: kept while the schedule returns the same
        object (its base gains outside every window), so a QP step does not rebuild them."""
        cached = self._tracking
        if cached is not None and cached[0] is prm:
            return cached[1], cached[2]
        w2 = prm.weight_vector(self.character) ** 2
        tracking = prm.b_t * np.diag(w2)
        self._tracking = (prm, w2, tracking)
        return w2, tracking

    def _constraint_regularisation(self, k: int) -> np.ndarray:
        """-CONSTRAINT_REGULARISATION I_k, built once per k."""
        block = self._constraint_blocks.get(k)
        if block is None:
            block = self._constraint_blocks[k] = -CONSTRAINT_REGULARISATION * np.eye(k)
        return block

    @staticmethod
    def _keep_cop_inside(K: np.ndarray, rhs: np.ndarray, x: np.ndarray, n: int,
                         a_p: np.ndarray, r_p: float, a_f: np.ndarray, r_f: float,
                         box: tuple[float, float]) -> np.ndarray:
        """Active-set step for u_lo <= p - s <= u_hi, where (p - s) F_y / m = a_p qdd + r_p and
        F_y / m = a_f qdd + r_f: both sides are linear in qdd. At most one side can be active
        while F_y > 0, and a convex QP whose unconstrained minimiser violates one linear
        inequality has its constrained minimiser on that inequality's boundary, so one
        equality-constrained re-solve on the violated side is exact."""
        qdd = x[:n]
        moment = dot(a_p, qdd) + r_p
        normal = dot(a_f, qdd) + r_f
        if normal <= 0.0:  # no normal force planned: the wrench check hands over to the fall
            return x
        if moment > box[1] * normal:
            bound = box[1]
        elif moment < box[0] * normal:
            bound = box[0]
        else:
            return x  # the plan's CoP is inside: the constraint is inactive
        row = a_p - bound * a_f  # moment = bound * normal  <=>  row qdd = bound r_f - r_p
        k = K.shape[0]
        K2 = np.zeros((k + 1, k + 1))
        K2[:k, :k] = K
        K2[:n, k] = row
        K2[k, :n] = row
        return solve(K2, np.append(rhs, bound * r_f - r_p))[:k]
