"""Balance by stepping (the stepping seed paper): feet planted while possible, a step when not.

Phases (`SteppingController.phase`):

* "feet_fixed": the momentum controller (`MomentumController`, unchanged) balances on both feet.
  Every step the capture point xi of the CM (`sim.ipm.capture_point`) is compared with the
  support: while it is no further than `capture_margin` beyond the toe or heel the feet stay
  planted.
* "pending": xi is beyond an edge. The feet-fixed controller goes on balancing; if xi comes back
  the step is called off. Otherwise the step starts `response_delay` s after xi first left (0 by
  default; the paper's 0.2 s delay of a human's response is the option). In either phase a
  failure of the feet-fixed controller starts the step at once, towards xi.
* "swing": one foot swings (the first step: the last of the character's `feet`; a follow-up:
  the foot left behind), the others stay planted (their constraint rows only: the
  observation's stance). The IPM (`sim.ipm.plan_step`, pivoting where the CoP will be: xi
  clamped to the stance foot) gives the CM's path over the swing and the capture point at
  touch-down, where the swing foot's sole centre lands (at most `max_step_fraction` of the leg
  length away); the plan is re-made from the measured CM at every swing QP solve
  (`sim.ipm.replan_step`), since a push may still act. At every solve the whole-body reference
  comes from inverse kinematics (`sim.ik.solve_ik`: stance foot fixed, CM at the IPM's, the
  swing foot on its path, flat, the pelvis at its standing angle) and the momentum QP balances
  it with the IPM's CM acceleration as its linear-momentum feed-forward, the CoP aimed at the
  pivot, the hard CoP (ZMP) constraint COP_MARGIN inside the stance foot, and the upper body's
  tracking weights scaled down so that it, not the legs, keeps the ZMP in
  (UPPER_WEIGHT_SCALE). The QP also tracks in task space (the seed's IK + ZMP QP): the swing
  sole on its planned path, the swing foot flat and the pelvis at the IK's angle, each a
  weighted PD row (FOOT_WEIGHT, FOOT_PITCH_WEIGHT, PELVIS_WEIGHT). While its planned normal
  force is below LOW_NORMAL_FORCE of the weight it solves at every step.
* "landed": the swing foot touches the ground (heel or toe within the contact margin, pitched
  at most LAND_PITCH) after half the swing, within LAND_TOLERANCE of its plan or late in the
  swing (LAND_FRACTION): an early heel strike short of the plan swings on. Both feet are in
  stance, the support runs from the rear heel to the
  front toe, and a feet-fixed momentum controller takes over: its legs' reference goes to the
  posture (from inverse kinematics) that puts the CM over the middle of that wider support, its
  QP keeps the CoP inside it, and the support wrench is shared between the feet by
  `sim.dynamics.inverse_dynamics_feet`. If it fails, the foot left behind steps (at most
  `max_steps` steps in a clip; a step's foot travels at most MAX_TRAVEL_FRACTION leg lengths).

Nothing here names a joint: the legs are the hinge chains between the root and each foot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.controllers.base import Cmrt, Controller, Observation
from sim.controllers.momentum import (
    FOOT_LIFT_LIMIT,
    WRENCH_VIOLATION_LIMIT,
    ControllerParams,
    GainScheduler,
    MomentumController,
    stance_bias,
)
from sim.dynamics import (
    GRAVITY,
    WRENCH_NO_NORMAL_FORCE,
    WRENCH_OK,
    WRENCH_REASONS,
    ModelArrays,
    body_point,
    checked_inverse_dynamics,
    feet_terms,
    forward_kinematics,
    momentum_bias,
)
from sim.ik import IK_DAMPING, IkResult, Target, leg_hinges, solve_ik
from sim.ipm import StepPlan, capture_point, plan_step, replan_step, step_direction
from sim.linalg import dot, matmul, matvec, tmatvec
from sim.trajectory import PoseTrajectory

#: A foot whose heel or toe is this low (m) touches the ground (the physics' contact margin).
TOUCHDOWN_HEIGHT = 0.0005
#: rad/s: the legs' reference rates (finite differences of two IK postures) are bounded so
#: that an IK jump near a straight knee cannot command a violent acceleration.
MAX_REFERENCE_RATE = 15.0
#: The feet-fixed phase's default gains over the spec's (`SteppingParams.feet_fixed_gains`):
#: cop_box (m) and d_l (s^-1)
FEET_FIXED_GAINS: tuple[tuple[str, float], ...] = (("cop_box", 0.005), ("d_l", 20.0))
# Fixed settings of the step (measured in docs/physics.md, "Stepping"); the ones a spec may set
# are `SteppingParams`.
#: m: the swing QP's CoP (ZMP) is kept this far inside the stance foot, and the IPM's pivot
#: this far inside its heel and toe: the CoP the plan assumes is one the QP can realise.
COP_MARGIN = 0.02
#: s^-2, s^-1: the swing leg's tracking gains: stiffer than the spec's k_t, d_t so that the
#: swing foot follows its planned path within the swing's 0.3 s.
SWING_STIFFNESS = 400.0
SWING_DAMPING = 40.0
#: Tracking weights during the swing: the swing leg's hinges, the stance leg's, and the factor
#: on every other hinge's weight. The upper body, not the legs, keeps the ZMP in while the
#: legs follow the IK (the stepping paper's QP moves only the upper body).
SWING_WEIGHT = 3.0
STANCE_WEIGHT = 0.3
UPPER_WEIGHT_SCALE = 0.1
#: Task-space tracking in the swing QP: weights of its rows (per (m/s^2)^2 for the swing
#: sole's x and y, per (rad/s^2)^2 for the foot's pitch and the pelvis' angle; the momentum
#: rows weigh 1 per (m/s^2)^2 of CM acceleration). The sole centre follows its planned path and
#: the foot stays flat at SWING_STIFFNESS / SWING_DAMPING; the pelvis goes to the IK posture's
#: angle (its standing angle) at PELVIS_STIFFNESS / PELVIS_DAMPING. Measured on push grids
#: (docs/physics.md, "Stepping"): weights of 0.3 on the sole or 1 on the pelvis fail most
#: steps (the tracking takes the normal force the ZMP needs); 0.1 / 0.3 / 0.1 land within
#: 4 cm of the plan from 200 N up.
FOOT_WEIGHT = 0.1
FOOT_PITCH_WEIGHT = 0.3
PELVIS_WEIGHT = 0.1
PELVIS_STIFFNESS = 100.0  # s^-2
PELVIS_DAMPING = 20.0  # s^-1
#: s: the planned foot path's velocity and acceleration are central differences over this.
FOOT_PATH_STEP = 0.001
#: The swing foot travels at most this many leg lengths from where it lifted (with
#: `max_step_fraction` from the stance foot): a follow-up step landing under the capture point
#: (1.35 m of travel in 0.3 s after a 300 N / 0.4 s push) does not land before the stance foot
#: rolls over; a shorter step and one more does.
MAX_TRAVEL_FRACTION = 1.0
#: s after the planned touch-down without one: balance is lost.
TOUCHDOWN_TIMEOUT = 0.25
#: m: the stance foot's heel or toe lifted this high during the swing loses balance (the swing
#: model holds the stance foot fixed while it rolls over its toe: 0.12 m is a 27 deg roll of
#: the 0.27 m foot; a follow-up step of a 0.4 s push rolls it 8.1 cm).
STANCE_LIFT_LIMIT = 0.12
#: m: after landing, a heel or toe this high loses balance (the rear heel of a long step rises
#: as the CM passes over the front foot): the feet-fixed limit.
LANDED_LIFT_LIMIT = FOOT_LIFT_LIMIT
#: s between the swing QP solves (feet fixed: 1/60 s): the swing's plan and IK change fast.
SWING_QP_PERIOD = 0.005
#: The swing foot cannot land before this fraction of the planned swing (it starts on the
#: ground).
MIN_SWING_FRACTION = 0.5
#: A swing foot on the ground has landed only when its sole centre is within
#: LAND_TOLERANCE (m) of the planned landing or LAND_FRACTION of the planned swing has passed.
LAND_TOLERANCE = 0.05
LAND_FRACTION = 0.9
#: rad: a swing foot lands when its heel or toe touches and it is pitched at most this much
#: (a backward step meets the ground toe first; waiting for both heel and toe left the foot
#: hovering a few mm up until the stance foot rolled over).
LAND_PITCH = 0.1
#: While the swing QP's planned normal force is below this fraction of the weight, it solves
#: at every simulation step instead of every SWING_QP_PERIOD: a plan held over 5 ms with a
#: small normal force lets the CoP run past the stance heel or toe.
LOW_NORMAL_FORCE = 0.3
#: s: the swing's support wrench may need a pulling ground this long before balance is lost
#: (feet fixed: at once); a swing foot scuffing the ground (contacts the swing model does not
#: have) gives such transients of a few ms.
NO_NORMAL_FORCE_LIMIT = 0.03
#: m: the CoP constraint of the QP after landing, inside the wider support.
LANDED_COP_MARGIN = 0.02
#: s: after touch-down the legs' reference goes from the landing posture to the held one over
#: this time (no jump in the reference).
SETTLE_TIME = 0.3
#: s: time constant of the push estimate, the measured CM acceleration minus the one the
#: controller's plan gives it (the push is not known to the controller), held over the rest of
#: the swing by the landing's IPM; held at 0 for PUSH_HOLD s after a touch-down (the landing's
#: impact is not a push).
PUSH_FILTER = 0.02
PUSH_HOLD = 0.05
#: After landing, a capture point beyond the wider support by more than LANDED_CAPTURE_MARGIN
#: (m) starts the next step at once (LANDED_MIN_TIME s after touch-down) instead of waiting for
#: the feet-fixed controller's failure.
LANDED_CAPTURE_MARGIN = 0.05
LANDED_MIN_TIME = 0.02


@dataclass(frozen=True)
class SteppingParams:
    """The settings of the step a spec may set (`sim.controllers.config.MomentumConfig`, where
    their ranges are); the rest are this module's constants."""

    #: s, from the capture point leaving the support to the step; the stepping paper's 0.2 s
    #: is an option (measured in docs/benchmarks.md, "Stepping")
    response_delay: float = 0.0
    capture_margin: float = 0.0  # m, how far beyond an edge the capture point may go unstepped
    step_duration: float = 0.3  # s, planned swing time
    clearance: float = 0.05  # m, the swing foot's lift at mid-swing
    #: longest step, as a fraction of the leg length, measured from the stance foot's sole
    #: centre (the leg's reach), so a follow-up step may pass the stance foot
    max_step_fraction: float = 0.7
    #: steps in one clip (the first and the follow-ups): a 300 N / 0.4 s push forward takes
    #: four (three long ones and one to settle)
    max_steps: int = 6
    #: Gains of the feet-fixed phase before a step over the spec's: by default the QP keeps its
    #: CoP 5 mm inside the foot and damps the CM at d_l 20, so the 300 N / 0.1 s push needs no
    #: step (the paper's Fig. 8); () keeps the spec's gains. The step and the landed
    #: controller keep the spec's gains (docs/physics.md, "Stepping").
    feet_fixed_gains: tuple[tuple[str, float], ...] = FEET_FIXED_GAINS


@dataclass
class StepRecord:
    """What one step did: plan, timing, and the QP's planned CoP at every swing solve."""

    detected: float  # s, the capture point first beyond the support
    start: float  # s, lift-off
    direction: int
    plan: StepPlan
    touchdown: float | None = None  # s
    length: float | None = None  # m, sole-centre displacement of the swing foot at touch-down
    land_x: float | None = None  # m, its sole centre at touch-down
    planned_land_x: float | None = None  # m, where the last re-plan put it
    solves: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    #: (t, planned CoP x, support lo, support hi, planned normal force N) per swing QP solve
    ik_error: list[tuple[float, float]] = field(default_factory=list)
    #: (t, |swing sole of the IK posture - planned position| m) per swing QP solve
    replans: list[tuple[float, float, float]] = field(default_factory=list)
    #: (t, landing x, capture point at touch-down) of every re-plan
    tracking: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    #: (t, planned - actual swing sole x m, y m, swing foot pitch rad, IK - actual pelvis
    #: angle rad) per swing QP solve
    stance_lift: float = 0.0  # m, the highest stance heel or toe during the swing
    push_estimate: float = 0.0  # m/s^2, the push estimate at lift-off
    c0: tuple[float, float] = (0.0, 0.0)  # m, the CM at lift-off
    cd0: tuple[float, float] = (0.0, 0.0)  # m/s, its velocity


class _Reference:
    """The swing QP's hinge reference, set before each solve: (q_r, qd_r, qdd_r)."""

    def __init__(self, n_hinges: int):
        self.value = (np.zeros(n_hinges), np.zeros(n_hinges), np.zeros(n_hinges))

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.value


class _HeldLegs:
    """A pose trajectory whose legs' hinges go from their state at touch-down (angles and
    rates) to a held posture over `blend` s (cubic Hermite), then stay (after landing): the
    feet-fixed QP then does not brake the legs' landing motion at once."""

    def __init__(self, base: PoseTrajectory):
        self.base = base
        self.hinges: list[int] = []
        self.start = self.rate = self.angles = np.zeros(0)
        self.t0 = 0.0
        self.blend = 1.0

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q, qd, qdd = self.base(t)
        if self.hinges:
            q = q.copy()
            qd = qd.copy()
            qdd = qdd.copy()
            T = self.blend
            u = min(max((t - self.t0) / T, 0.0), 1.0)
            h00, h10, h01 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2
            d00, d10, d01 = 6 * u**2 - 6 * u, 3 * u**2 - 4 * u + 1, -6 * u**2 + 6 * u
            e00, e10, e01 = 12 * u - 6, 6 * u - 4, -12 * u + 6
            if u >= 1.0:
                d00 = d10 = d01 = e00 = e10 = e01 = 0.0
            p0, v0, p1 = self.start, self.rate, self.angles
            q[self.hinges] = h00 * p0 + h10 * T * v0 + h01 * p1
            qd[self.hinges] = (d00 * p0 + d10 * T * v0 + d01 * p1) / T
            qdd[self.hinges] = (e00 * p0 + e10 * T * v0 + e01 * p1) / (T * T)
        return q, qd, qdd


class _PlannedMomentum(MomentumController):
    """The momentum QP of the swing: its desired momentum rates follow the IPM plan (the CM
    acceleration as a feed-forward, the CoP at the pivot) instead of holding still over the
    support centre."""

    accel = np.zeros(2)
    p_des = 0.0
    #: The swing's task-space terms (H, g) added to the QP's cost (`extra_objective`).
    task: tuple[np.ndarray, np.ndarray] | None = None

    def extra_objective(self) -> tuple[np.ndarray, np.ndarray] | None:
        return self.task

    def desired_rates(self, prm: ControllerParams, c: np.ndarray, cd: np.ndarray,
                      support: tuple[float, float], c_ref: tuple[float, float],
                      cd_ref: tuple[float, float]) -> tuple[np.ndarray, float]:
        m = self.mass
        L = m * cd
        ldot = np.array([
            prm.k_l * m * (c_ref[0] - c[0]) + prm.d_l * (m * cd_ref[0] - L[0]) + m * self.accel[0],
            -prm.d_l_vertical * L[1] + m * self.accel[1],
        ])
        F = ldot + np.array([0.0, m * GRAVITY])
        return ldot, (self.p_des - c[0]) * F[1] + c[1] * F[0]


class SteppingController(Controller):
    """The momentum controller with stepping (module doc); the Controller protocol, with
    `stance` (indices into the character's feet, None for all) read by the rollout."""

    @property
    def foot_steps(self) -> int | None:
        """Steps taken since `reset` (started ones included)."""
        return len(self.steps)

    def __init__(self, character: Character, schedule: GainScheduler,
                 trajectory: PoseTrajectory, arrays: ModelArrays | None = None,
                 dt: float = 0.001, mu: float = 1.0, params: SteppingParams | None = None):
        self.character = character
        self.params = params or SteppingParams()
        self.arrays = arrays or ModelArrays.from_character(character)
        self.dt = dt
        self.mu = mu
        self.trajectory = trajectory
        ch = character
        nf = len(ch.feet)
        if nf < 2:
            raise ValueError("stepping needs a character with at least two feet")
        #: The first step swings the last foot (feet side by side: any one would do); a
        #: follow-up step swings the foot left behind.
        self.swing = nf - 1
        self.support_feet = tuple(range(nf - 1))
        self.legs = [leg_hinges(ch, int(f)) for f in ch.feet]
        top = self.legs[self.swing][0] + 1  # the body below the leg's first hinge
        sole0 = 0.5 * (ch.heel0[self.swing] + ch.toe0[self.swing])
        self.leg_length = float(np.hypot(*(ch.anchor0[top] - sole0)))
        self.schedule = schedule  # the spec's gains
        fixed = (GainScheduler(replace(schedule.base, **dict(self.params.feet_fixed_gains)),
                               schedule.entries)
                 if self.params.feet_fixed_gains else schedule)
        self.feet_fixed = MomentumController(ch, fixed, trajectory, self.arrays, dt, mu)
        self.qp_every = max(1, int(round(SWING_QP_PERIOD / dt)))
        base = schedule.base
        self._ref = _Reference(ch.n_hinges)
        #: Per swing foot: the swing QP's gains (CoP constraint on, that leg's tracking weight
        #: raised, the stance legs' lowered) and the QP itself.
        self.swing_qps: list[_PlannedMomentum] = []
        for sw in range(nf):
            # The upper body is what keeps the ZMP in while the legs follow the IK (the paper's
            # QP moves only the upper body): its tracking weights are scaled down.
            leg_set = {j for leg in self.legs for j in leg}
            w_file = base.weight_vector(ch)
            weights = {ch.hinge_names[j]: float(w_file[j]) * UPPER_WEIGHT_SCALE
                       for j in range(ch.n_hinges) if j not in leg_set}
            weights.update({ch.hinge_names[j]: STANCE_WEIGHT
                            for f in range(nf) if f != sw for j in self.legs[f]})
            weights.update({ch.hinge_names[j]: SWING_WEIGHT for j in self.legs[sw]})
            prm = replace(base, cop_box=COP_MARGIN,
                          weights={**base.weights, **weights})
            self.swing_qps.append(_PlannedMomentum(ch, GainScheduler(prm, []), self._ref,
                                                   self.arrays, dt, mu))
        self._held = _HeldLegs(trajectory)
        landed = GainScheduler(replace(schedule.base, cop_box=LANDED_COP_MARGIN), schedule.entries)
        self.landed_qp = MomentumController(ch, landed, self._held, self.arrays, dt, mu)
        # The feet are apart after the step: share the wrench by weight, not by foot torques.
        self.landed_qp.feet_apart = True
        self.landed_qp.foot_lift_limit = LANDED_LIFT_LIMIT
        self.steps: list[StepRecord] = []
        self.reset()

    # ---- the Controller protocol ----------------------------------------------------------
    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None:
        self.reference = reference
        self.feet_fixed.reset(observation, reference)
        self.phase = "feet_fixed"
        self.stance: tuple[int, ...] | None = None
        self.lost: str | None = None
        self.c_ref = self.feet_fixed.c_ref
        self.steps = []
        self._detected = 0.0
        self._k = 0
        self._violations = 0
        self._plant: list[tuple[np.ndarray, float]] = []
        self.push = 0.0  # m/s^2, the estimated horizontal CM acceleration from outside
        self._cd_prev: float | None = None
        self._a_plan = 0.0  # m/s^2, the CM acceleration the last step's plan gave
        self._reach: float | None = None
        #: rad: the root's (pelvis') angle at the clip's first step (standing).
        self._upright: float | None = None

    def act(self, obs: Observation, t: float) -> np.ndarray:
        """Hinge torques for this step (see the module doc for the phases)."""
        self._observe_push(obs, t)
        if self._upright is None:
            self._upright = float(obs.q[2])
        if self.phase in ("feet_fixed", "pending"):
            tau = self._feet_fixed(obs, t)
            self._planned_accel(obs, self.feet_fixed.qdd, 0.0)
            return tau
        if self.phase == "swing":
            tau = self._swing(obs, t)
            self._planned_accel(obs, self.swing_qp.qdd, self._b_L0)
            return tau
        tau = self.landed_qp.act(obs, t)
        self._planned_accel(obs, self.landed_qp.qdd, 0.0)
        self.c_ref = self.landed_qp.c_ref
        prm = self.params
        xi = capture_point(obs.c, obs.cd)
        d_cp = step_direction(xi, obs.support, LANDED_CAPTURE_MARGIN)
        early = d_cp != 0 and t - (self.steps[-1].touchdown or t) >= LANDED_MIN_TIME
        if self.landed_qp.lost is not None or early:
            # The feet-fixed balance over the wider support fails (typically the rear heel
            # lifts as the CM runs on over the front foot), or the capture point is already
            # beyond it: bring the foot left behind forward (or, stepping back, the front
            # foot back) under the capture point.
            d = d_cp if d_cp != 0 else (1 if xi >= 0.5 * sum(obs.support) else -1)
            if len(self.steps) < prm.max_steps:
                swing = int(np.argmin(d * np.asarray(obs.sole_x)))
                self._detected = t
                self._start_step(obs, t, d, swing)
            elif self.landed_qp.lost is not None:
                self.lost = self.landed_qp.lost
        return tau

    def _observe_push(self, obs: Observation, t: float) -> None:
        """Update the push estimate: the measured CM acceleration (a finite difference of the
        CM velocity over one step) minus the one the controller's last plan gave it, low-passed
        over PUSH_FILTER s, and held at 0 for PUSH_HOLD s after a touch-down. Only the
        measured state enters: the force is unknown here."""
        tau_f = PUSH_FILTER
        cdx = float(obs.cd[0])
        landing = (self.phase == "landed" and self.steps
                   and t - (self.steps[-1].touchdown or t) < PUSH_HOLD)
        if landing:
            self.push = 0.0
        elif self._cd_prev is not None:
            raw = (cdx - self._cd_prev) / self.dt - self._a_plan
            self.push += min(self.dt / tau_f, 1.0) * (raw - self.push)
        self._cd_prev = cdx

    def _planned_accel(self, obs: Observation, qdd: np.ndarray, b_L0: float) -> None:
        """The horizontal CM acceleration (m/s^2) the active QP's qdd gives (b_L0: its
        velocity-product term when known)."""
        self._a_plan = (dot(obs.A_L[0], qdd) + b_L0) / self.character.total_mass

    # ---- phases ---------------------------------------------------------------------------
    def _feet_fixed(self, obs: Observation, t: float) -> np.ndarray:
        tau = self.feet_fixed.act(obs, t)
        self.c_ref = self.feet_fixed.c_ref
        prm = self.params
        d = step_direction(capture_point(obs.c, obs.cd), obs.support, prm.capture_margin)
        if self.phase == "feet_fixed" and d != 0:
            self.phase, self._detected = "pending", t
        elif self.phase == "pending" and d == 0:
            self.phase = "feet_fixed"  # recovered in place: no step
        if self.feet_fixed.lost is not None:
            # The feet-fixed controller fails (a heel or toe lifts, its wrench inadmissible):
            # step at once, towards the capture point (the paper's rule: stepping takes over
            # when balance with the feet planted fails), delay or not.
            if self.phase == "feet_fixed":
                self._detected = t
            xi = capture_point(obs.c, obs.cd)
            self._start_step(obs, t, 1 if xi >= 0.5 * sum(obs.support) else -1, self.swing)
        elif self.phase == "pending" and t - self._detected >= prm.response_delay - 1e-9:
            self._start_step(obs, t, d, self.swing)
        return tau

    def _start_step(self, obs: Observation, t: float, direction: int, swing: int) -> None:
        prm = self.params
        a = self.arrays
        alpha, p, _o = forward_kinematics(obs.q, a.parent, a.a_par, a.a_chi)
        sw = self.swing = swing
        self.support_feet = tuple(f for f in range(len(a.feet)) if f != sw)
        sole = body_point(alpha, p, int(a.feet[sw]), a.sole_local[sw])
        lo = min(body_point(alpha, p, int(a.feet[f]), a.heel_local[f])[0]
                 for f in self.support_feet)
        hi = max(body_point(alpha, p, int(a.feet[f]), a.toe_local[f])[0]
                 for f in self.support_feet)
        # The IPM pivots where the CoP will be: under the capture point as far as the stance
        # foot reaches (its toe or heel edge when the capture point is beyond it).
        pivot = min(max(capture_point(obs.c, obs.cd), lo + COP_MARGIN), hi - COP_MARGIN)
        # The leg's reach is measured from the stance foot furthest along the step.
        self._reach = direction * max(direction * float(body_point(alpha, p, int(a.feet[f]),
                                                                   a.sole_local[f])[0])
                                      for f in self.support_feet)
        if MAX_TRAVEL_FRACTION > 0.0:
            # The swing foot travels at most MAX_TRAVEL_FRACTION leg lengths: the landing is
            # limited from whichever of the stance foot's reach and the swing foot's start
            # gives the nearer bound.
            travel = MAX_TRAVEL_FRACTION * self.leg_length
            if direction * (float(sole[0]) + direction * travel) < direction * (
                    self._reach + direction * self._max_step()):
                self._reach = float(sole[0]) + direction * (travel - self._max_step())
        plan = plan_step(t, obs.c, obs.cd, pivot, (float(sole[0]), float(sole[1])), direction,
                         prm.step_duration, prm.clearance, self._max_step(),
                         reach_from=self._reach, push=self.push)
        self._plant = [(body_point(alpha, p, int(a.feet[f]), a.sole_local[f]),
                        float(alpha[int(a.feet[f])])) for f in self.support_feet]
        self.steps.append(StepRecord(self._detected, t, direction, plan,
                                     push_estimate=self.push,
                                     c0=(float(obs.c[0]), float(obs.c[1])),
                                     cd0=(float(obs.cd[0]), float(obs.cd[1]))))
        self._plan = plan
        self.phase = "swing"
        self.stance = self.support_feet
        self._k = 0
        self._violations = 0
        self._pulling = 0
        self._b_L0 = 0.0
        self._normal = math.inf  # N, the last swing solve's planned normal force
        self.swing_qp = self.swing_qps[sw]
        self.swing_qp.reset(None, None)
        self.swing_qp.p_des = pivot

    def _targets(self, t: float) -> list[Target]:
        """IK targets of the swing at time t: stance feet where they were planted, flat; the
        CM on the IPM's path (x); the swing foot on its planned path, flat."""
        a = self.arrays
        plan = self._plan
        out = []
        for f, (sole, ang) in zip(self.support_feet, self._plant, strict=True):
            b = int(a.feet[f])
            out.append(Target("point", (float(sole[0]), float(sole[1])), b,
                              tuple(a.sole_local[f])))
            out.append(Target("angle", (ang,), b))
        pos, _v, _acc = plan.path.state(t)
        out.append(Target("cm", (float(pos[0]),)))
        if self._upright is not None:
            out.append(Target("angle", (self._upright,), 0))
        b = int(a.feet[self.swing])
        out.append(Target("point", plan.foot(t), b, tuple(a.sole_local[self.swing])))
        out.append(Target("angle", (0.0,), b))
        return out

    def _swing_ik(self, q0: np.ndarray, t: float) -> IkResult:
        """The swing's whole-body IK posture at t (every leg hinge and the root)."""
        return solve_ik(q0, self.arrays, self.character.limits, self._targets(t),
                        self._leg_dofs(), damping=IK_DAMPING)

    def _max_step(self) -> float:
        """m: the longest step."""
        return self.params.max_step_fraction * self.leg_length

    def _leg_dofs(self) -> list[int]:
        return [0, 1, 2] + [ROOT_DOF + j for leg in self.legs for j in leg]

    def _swing(self, obs: Observation, t: float) -> np.ndarray:
        rec = self.steps[-1]
        a = self.arrays
        lo, hi = obs.support
        m = self.character.total_mass
        low = self._normal < LOW_NORMAL_FORCE * m * GRAVITY
        if self._k % self.qp_every == 0 or low:
            if self._k > 0:  # a push may still act: the landing follows the measured CM
                self._plan = replan_step(self._plan, t, obs.c, obs.cd, self._max_step(),
                                         self._reach, self.push)
                rec.replans.append((t, self._plan.land[0], self._plan.capture_at_land))
            plan = self._plan
            h = self.qp_every * self.dt
            ik_now = self._swing_ik(obs.q, t)
            ik_next = self._swing_ik(ik_now.q, t + h)
            alpha, p, _o = forward_kinematics(ik_now.q, a.parent, a.a_par, a.a_chi)
            sole = body_point(alpha, p, int(a.feet[self.swing]), a.sole_local[self.swing])
            fx, fy = plan.foot(t)
            rec.ik_error.append((t, float(math.hypot(sole[0] - fx, sole[1] - fy))))
            q_r, qd_r, _ = self.trajectory(t)
            q_r = q_r.copy()
            qd_r = qd_r.copy()
            legs = [j for leg in self.legs for j in leg]
            hq = obs.q[ROOT_DOF:]
            hqd = obs.qd[ROOT_DOF:]
            q_r[legs] = ik_now.q[ROOT_DOF:][legs]
            qd_r[legs] = np.clip((ik_next.q[ROOT_DOF:][legs] - q_r[legs]) / h,
                                 -MAX_REFERENCE_RATE, MAX_REFERENCE_RATE)
            # The QP's tracking law is k_t (q_r - q) + d_t (qd_r - qd) + qdd_r; the swing leg
            # needs the stiffer swing gains, so its qdd_r carries the difference.
            qdd_r = np.zeros_like(q_r)
            sp = self.swing_qp.schedule.base
            sw_leg = self.legs[self.swing]
            qdd_r[sw_leg] = ((SWING_STIFFNESS - sp.k_t) * (q_r[sw_leg] - hq[sw_leg])
                             + (SWING_DAMPING - sp.d_t) * (qd_r[sw_leg] - hqd[sw_leg]))
            self._ref.value = (q_r, qd_r, qdd_r)
            self.swing_qp.task = self._task_terms(obs, t, ik_now.q, ik_next.q, h, rec)
            pos, vel, acc = plan.path.state(t)
            # The ground supplies the IPM's acceleration less the push's.
            self.swing_qp.accel = acc - np.array([plan.path.push, 0.0])
            self.c_ref = (float(pos[0]), 0.0)
            bias = stance_bias(a, obs)
            qdd = self.swing_qp.solve(t, obs.q, obs.qd, obs.c, obs.cd, obs.A_L, obs.A_H, obs.Js,
                                      (lo, hi), self.c_ref, (float(vel[0]), 0.0), lambda: bias)
            b_L, b_H, _b_S = bias
            self._b_L0 = float(b_L[0])
            fxg = float(dot(obs.A_L[0], qdd) + b_L[0])
            fyg = float(dot(obs.A_L[1], qdd) + b_L[1] + m * GRAVITY)
            hdot = float(dot(obs.A_H, qdd) + b_H)
            cop = (float(obs.c[0]) + (hdot - float(obs.c[1]) * fxg) / fyg if fyg > 0.0
                   else math.nan)
            rec.solves.append((t, cop, lo, hi, fyg))
            self._normal = fyg
        self._k += 1
        plan = self._plan
        tau, code, _cop = checked_inverse_dynamics(obs.M, obs.h, obs.Js, self.swing_qp.qdd,
                                                   obs.sole_x, lo, hi, self.mu)
        self._violations = self._violations + 1 if code != WRENCH_OK else 0
        self._pulling = self._pulling + 1 if code == WRENCH_NO_NORMAL_FORCE else 0
        lift = max(obs.points[:, 1].tolist())
        rec.stance_lift = max(rec.stance_lift, lift)
        if (self._pulling * self.dt > NO_NORMAL_FORCE_LIMIT
                or self._violations * self.dt > WRENCH_VIOLATION_LIMIT):
            self.lost = f"step_{WRENCH_REASONS[code]}"
        elif lift > STANCE_LIFT_LIMIT:
            self.lost = "step_foot_lift"
        elif t - plan.t0 >= MIN_SWING_FRACTION * plan.duration and self._touching(obs, t):
            self._land(obs, t)
        elif t - plan.t0 > plan.duration + TOUCHDOWN_TIMEOUT:
            self.lost = "step_no_touchdown"
        return tau

    def _task_terms(self, obs: Observation, t: float, ik_now: np.ndarray, ik_next: np.ndarray,
                    h: float, rec: StepRecord) -> tuple[np.ndarray, np.ndarray] | None:
        """The swing QP's task-space terms: the swing foot's sole centre on its planned path
        and flat, the pelvis at the IK posture's angle, each as a weighted least-squares row
        w |J qdd + b - a_des|^2 with a_des = K (r_ref - r) + D (v_ref - v) + a_ref (J, b: the
        swing foot's rows of the support Jacobian and their velocity-product terms)."""
        if FOOT_WEIGHT <= 0.0 and FOOT_PITCH_WEIGHT <= 0.0 and PELVIS_WEIGHT <= 0.0:
            return None
        a = self.arrays
        n = self.character.ndof
        sw = self.swing
        alpha, p, o = forward_kinematics(obs.q, a.parent, a.a_par, a.a_chi)
        Js, _heel, _toe, sole = feet_terms(alpha, p, o, a.path, a.feet, a.sole_local,
                                           a.heel_local, a.toe_local, n)
        _bL, _bH, b_S = momentum_bias(obs.q, obs.qd, a.parent, a.a_par, a.a_chi, a.mass,
                                      a.feet, a.sole_local)
        J = Js[3 * sw:3 * sw + 3]
        b = b_S[3 * sw:3 * sw + 3]
        r = np.array([sole[sw][0], sole[sw][1], alpha[int(a.feet[sw])]])
        v = matvec(J, obs.qd)
        plan = self._plan
        d = FOOT_PATH_STEP
        f0, fp, fm = (np.array(plan.foot(u)) for u in (t, t + d, t - d))
        r_ref = np.array([f0[0], f0[1], 0.0])
        v_ref = np.array([*((fp - fm) / (2 * d)), 0.0])
        a_ref = np.array([*((fp - 2 * f0 + fm) / (d * d)), 0.0])
        a_des = SWING_STIFFNESS * (r_ref - r) + SWING_DAMPING * (v_ref - v) + a_ref
        w = np.array([FOOT_WEIGHT, FOOT_WEIGHT, FOOT_PITCH_WEIGHT])
        H = matmul(J.T, w[:, None] * J)
        g = tmatvec(J, w * (a_des - b))
        pel = (PELVIS_STIFFNESS * (ik_now[2] - obs.q[2])
               + PELVIS_DAMPING * ((ik_next[2] - ik_now[2]) / h - obs.qd[2]))
        H[2, 2] += PELVIS_WEIGHT
        g[2] += PELVIS_WEIGHT * pel
        rec.tracking.append((t, float(r_ref[0] - r[0]), float(r_ref[1] - r[1]), float(r[2]),
                             float(ik_now[2] - obs.q[2])))
        return H, g

    def _touching(self, obs: Observation, t: float) -> bool:
        """The swing foot has landed: its heel or toe on the ground (within TOUCHDOWN_HEIGHT),
        pitched at most LAND_PITCH, and either near its planned landing (LAND_TOLERANCE) or
        late in its swing (LAND_FRACTION): a foot that meets the ground early and short of its
        plan (its heel striking, a scuff mid-swing) swings on."""
        a = self.arrays
        alpha, p, _o = forward_kinematics(obs.q, a.parent, a.a_par, a.a_chi)
        b = int(a.feet[self.swing])
        heel = body_point(alpha, p, b, a.heel_local[self.swing])
        toe = body_point(alpha, p, b, a.toe_local[self.swing])
        if min(heel[1], toe[1]) > TOUCHDOWN_HEIGHT or abs(float(alpha[b])) > LAND_PITCH:
            return False
        plan = self._plan
        sole = body_point(alpha, p, b, a.sole_local[self.swing])
        return (t - plan.t0 >= LAND_FRACTION * plan.duration
                or abs(float(sole[0]) - plan.land[0]) <= LAND_TOLERANCE)

    def _land(self, obs: Observation, t: float) -> None:
        """Touch-down: both feet in stance; the feet-fixed controller takes over with the legs'
        reference the posture that puts the CM over the middle of the wider support."""
        a = self.arrays
        rec = self.steps[-1]
        alpha, p, _o = forward_kinematics(obs.q, a.parent, a.a_par, a.a_chi)
        targets = []
        lo, hi = math.inf, -math.inf
        for f in range(len(a.feet)):
            b = int(a.feet[f])
            sole = body_point(alpha, p, b, a.sole_local[f])
            heel = body_point(alpha, p, b, a.heel_local[f])
            toe = body_point(alpha, p, b, a.toe_local[f])
            lo, hi = min(lo, heel[0]), max(hi, toe[0])
            targets.append(Target("point", (float(sole[0]), max(float(sole[1]), 0.0) - 1e-4), b,
                                  tuple(a.sole_local[f])))
            targets.append(Target("angle", (0.0,), b))
            if f == self.swing:
                rec.length = float(sole[0] - rec.plan.start[0])
                rec.land_x = float(sole[0])
                rec.planned_land_x = float(self._plan.land[0])
        targets.append(Target("cm", (0.5 * (lo + hi),)))
        held = solve_ik(obs.q, a, self.character.limits, targets, self._leg_dofs())
        legs = [j for leg in self.legs for j in leg]
        self._held.hinges = legs
        self._held.angles = held.q[ROOT_DOF:][legs].copy()
        self._held.start = obs.q[ROOT_DOF:][legs].copy()
        self._held.rate = obs.qd[ROOT_DOF:][legs].copy()
        self._held.t0 = t
        self._held.blend = SETTLE_TIME
        rec.touchdown = t
        self.phase = "landed"
        self.stance = None
        self.landed_qp.reset(None, self.reference)
