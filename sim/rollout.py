"""The rollout: one task spec simulated under the balance controller, measured, and scored.

`Rollout(spec)` builds the character, the task, the physics (with the task's props) and the
controllers once; `run(cmrt)` resets them and simulates the clip (preparation + task + decay)
at 1 ms steps. The loop only coordinates: observe (state and model terms), check for a fall,
act (the active controller's torques), task events, step, measure, record.

Measurements, every step: the centre of pressure p(t) from the feet's contact feedback, the
support centre s(t) (middle of the stance feet's heel-toe interval: both feet, or the
support foot while the other swings; `Controller.stance`), the CP error e = p - s. The
objective is the 2-norm of e over the steps that had ground contact (metres), plus the task's
penalty (e.g. a ball not caught).

A fall ends the clip: a body other than a foot touching the ground, the CM below
FALL_CM_FRACTION of its standing height, or the controller losing balance (see
`sim.controllers.momentum.MomentumController`). The objective of a fall is `fall_penalty`: at
least sqrt(steps) x the support length, more than any non-fall objective can be (|e| never
exceeds the support length), and larger the earlier the fall, so every fall ranks worse than
every non-fall and later falls rank better. The fall's direction is the side of the support
centre where the CM's capture point c_x + cd_x sqrt(c_y / g) lies at the fall.
When the task reports that the interaction the CMRT anticipates did not happen
(`Task.interaction_failed`, e.g. a punch that met nothing), the CMRT is released
(`ReleasableCmrt`): from then the controller's reference eases back to its own (the support
centre, no displacement) over RELEASE_TIME, and it balances purely reactively (paper 6.1.4).
With traces on, a clip whose controller lost balance goes on under the fall controller until
a body touches the ground or the CM drops, to show the fall (frames at FRAME_RATE for replay).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from sim.character import ROOT_DOF
from sim.controllers import FallController
from sim.controllers.base import Cmrt, Controller, Observation, stance_terms
from sim.controllers.registry import ControllerContext, build_controller
from sim.dynamics import (
    GRAVITY,
    ModelArrays,
    PackedModel,
    forward_kinematics,
    step_model_held,
    step_model_packed,
)
from sim.evaluation import Evaluation
from sim.physics import CONTACT_SOFT_CFM, DT, FRICTION_MU, WORLD_ERP, DivergenceError, Physics
from sim.props import PropDef
from sim.recording import FRAME_EVERY, Recorder
from sim.spec import TaskSpec
from sim.standing import standing_state
from sim.trajectory import PoseTrajectory, ease

FALL_CM_FRACTION = 0.6  # a CM below 60 % of its standing height is a fall
MIN_CONTACT_FORCE = 1.0  # N: below this total normal force a step has no CP measurement
DIVERGENCE_CHECK_STEPS = 10  # the state is checked for divergence every this many steps
CUT_CHECK_STEPS = 10  # a run with `stop_above` reads its bound every this many steps
#: s: a released CMRT goes from its value at the release to 0 by a quintic ease this long, not
#: at once, so that the reference (and a vertical CMRT's crouch posture) has no jump; six QP
#: solves at the controller's 60 Hz.
RELEASE_TIME = 0.1


class ReleasableCmrt:
    """A CMRT the rollout can drop mid-clip: `cmrt(t)` unchanged (the same values, bit for
    bit) until `release(t_r)`, then its value at t_r eased to 0 over `ramp` s, so that the
    controller's reference returns to its own (support centre, no displacement)."""

    def __init__(self, cmrt: Cmrt, ramp: float = RELEASE_TIME):
        self.cmrt = cmrt
        self.ramp = ramp
        self.released_at: float | None = None
        self._held = (0.0, 0.0)  # m, (horizontal, vertical) displacement at the release

    def release(self, t: float) -> None:
        """Drop the CMRT from t (s) on."""
        v = self.cmrt(t)
        if isinstance(v, tuple | list | np.ndarray):
            self._held = (float(v[0]), float(v[1]) if len(v) > 1 else 0.0)
        else:
            self._held = (float(v), 0.0)
        self.released_at = t

    def __call__(self, t: float) -> object:
        at = self.released_at
        if at is None or t <= at:
            return self.cmrt(t)
        w = 1.0 - ease((t - at) / self.ramp)[0] if self.ramp > 0.0 else 0.0
        return (w * self._held[0], w * self._held[1])


def fall_penalty(fall_time: float, length: float, steps: int, support_length: float) -> float:
    """Objective of a clip that fell at `fall_time` s of `length`: in (F0, 2 F0], F0 being an
    upper bound of any non-fall objective, sqrt(steps) x support length."""
    f0 = math.sqrt(steps) * support_length
    return f0 * (2.0 - min(max(fall_time / length, 0.0), 1.0))


def fall_direction(c: np.ndarray, cd: np.ndarray, support_centre: float) -> str:
    """"forward" (+x) or "backward": the side of the support centre where the CM's capture
    point c_x + cd_x sqrt(c_y / g) lies."""
    xi = c[0] + cd[0] * math.sqrt(max(c[1], 0.0) / GRAVITY)
    return "forward" if xi >= support_centre else "backward"


class Rollout:
    """A task spec's physics, task and controllers, built once and reset for each run.

    `extra_props`: props placed in the world beside the task's (the controller and the task do
    not know them; a measurement's load, e.g. the cost per prop in bench/prop_scaling.py)."""

    def __init__(self, spec: TaskSpec, extra_props: Sequence[PropDef] = ()):
        self.spec = spec
        ch = spec.load_character()
        self.character = ch
        self.support_length = ch.support_length
        self.arrays = ModelArrays.from_character(ch)
        self.task = spec.task.build(spec, ch)
        props = self.task.props
        self.physics = Physics(ch, self.arrays, (*props, *extra_props) if extra_props else props)
        self.q0 = standing_state(ch, self.arrays, self.task.initial_pose)
        # Start with the ground contacts already loaded: sink the body by the static
        # penetration of a soft contact, depth = (m g / contacts) / k with the contact
        # stiffness k = ERP / (dt CFM); otherwise the first steps score a loading transient.
        contacts = 2 * len(ch.feet)
        k_contact = WORLD_ERP / (DT * CONTACT_SOFT_CFM)
        self.q0[1] -= ch.total_mass * GRAVITY / contacts / k_contact
        _, p0, _ = forward_kinematics(self.q0, self.arrays.parent, self.arrays.a_par,
                                      self.arrays.a_chi)
        self.cm0 = (ch.mass[:, None] * p0).sum(axis=0) / ch.mass.sum()
        self.trajectory = PoseTrajectory(self.q0[ROOT_DOF:], self.task.motions)
        self.controller: Controller = build_controller(
            spec.controller, ControllerContext(spec, ch, self.arrays, self.trajectory, DT,
                                               FRICTION_MU, self.q0.copy()))
        self.fall_controller = FallController(ch, DT)
        self.steps = int(round(spec.clip.length / DT))

    def run(self, cmrt: Cmrt | None = None, traces: bool = False,
            stop_above: Callable[[], float] | None = None) -> Evaluation:
        """Simulate the clip with the CMRT (None: no anticipation) and score it.

        stop_above: read every CUT_CHECK_STEPS steps, a bound b (inf: none); once the
        objective's lower bound min(sqrt(running sum of e^2), F0) exceeds b the run stops and
        returns that lower bound as its objective with `cut=True` (`optim.rankcut` uses it for
        the candidate that already ranks last). Every other run is unchanged bit for bit."""
        cpu0 = time.process_time()
        clip = _Clip(self, cmrt, traces)
        for k in range(self.steps):
            t = k * DT
            if (stop_above is not None and k % CUT_CHECK_STEPS == 0 and not clip.lost
                    and clip.lower_bound() > stop_above()):
                return clip.cut(cpu0)
            clip.observe(k, t)
            if clip.fell_physically(t):
                break
            tau = clip.act(t)
            if clip.loses_balance(t):
                if not traces:
                    break
                tau = clip.hand_over(t)
            clip.frame(k, t)
            fy, cop = clip.step(tau, t)
            clip.measure(k, t, fy, cop)
        return clip.result(cpu0)

    def close(self) -> None:
        self.physics.close()


class _Clip:
    """One run of a `Rollout`: its state and the loop's pieces, in the order the loop calls
    them each step: `observe` (state, model terms, the stance feet's terms), `fell_physically`
    (the fall rules), `act` (the active controller's torques), `loses_balance` / `hand_over`
    (the controller's own fall and the fall controller), `frame` (replay), `step` (torques,
    task events, contacts, ODE step, contact feedback), `measure` (CP error and traces); then
    `result` or `cut`."""

    __slots__ = (
        "rollout", "phys", "task", "events", "balance", "active", "releasable", "rec",
        "foot_of_point", "n_feet", "cm_floor", "sq_sum", "max_e", "contact_steps", "fall_time",
        "fall_reason", "direction", "lost", "c_ref", "k_done", "f0", "pargs", "M", "h", "c",
        "cd", "A_L", "A_H", "Js", "pts", "sole_x", "held", "held_qdd", "tau_held", "neg_limit",
        "limit", "lo", "hi", "s", "clearance", "code", "top", "stance", "obs_terms",
    )

    def __init__(self, rollout: Rollout, cmrt: Cmrt | None, traces: bool):
        self.rollout = rollout
        ch, phys, task = rollout.character, rollout.physics, rollout.task
        self.phys, self.task = phys, task
        phys.reset(rollout.q0)
        task.reset(phys)
        self.balance = self.active = rollout.controller
        # Only a task that can report a failed interaction gets the wrapper: every other clip
        # hands the controller the CMRT itself.
        self.releasable = (ReleasableCmrt(cmrt, RELEASE_TIME) if cmrt is not None and task.events
                           and task.reports_failure else None)
        self.balance.reset(None, self.releasable or cmrt)
        self.events = task.events
        self.foot_of_point = np.repeat(ch.feet, 2).tolist()
        self.n_feet = len(ch.feet)
        self.cm_floor = FALL_CM_FRACTION * rollout.cm0[1]
        self.rec = Recorder(rollout.steps, phys) if traces else None
        self.sq_sum = 0.0
        self.max_e = 0.0
        self.contact_steps = 0
        self.fall_time: float | None = None
        self.fall_reason: str | None = None
        self.direction: str | None = None
        self.lost = False
        self.c_ref = (rollout.cm0[0], 0.0)
        self.k_done = 0
        # Lower bound of the objective at any point of the clip: the running error norm grows
        # (float sums of squares and sqrt are monotone, task penalties are >= 0), and a later
        # fall scores at least F0 = sqrt(steps) x support length.
        self.f0 = math.sqrt(rollout.steps) * rollout.support_length
        # The model terms are written into these arrays every step (step_model_packed): the
        # Observation's arrays hold this step's values only, as q and qd (read_state) do.
        # (`PackedModel`: views of one buffer, the constants in three arrays, so that the one
        # compiled call per step unboxes 6 arguments, not 24.)
        pack = PackedModel(rollout.arrays, ch.ndof)
        (self.M, self.h, self.c, self.cd, self.A_L, self.A_H, self.Js, self.pts,
         self.sole_x) = pack.arrays()
        self.pargs = pack.args()
        # Steps between QP solves: the model terms, the held accelerations' inverse dynamics
        # and the torque clamp in one compiled call (`step_model_held`), when the balance
        # controller offers them (`Controller.held_torque_step`); the same torques and
        # judgement as its `act`, bit for bit.
        self.neg_limit, self.limit = phys.torque_bounds
        self.tau_held = np.empty(len(self.limit))
        self.held = False

    def lower_bound(self) -> float:
        """A lower bound of this clip's objective so far (see `Rollout.run`'s stop_above)."""
        return min(math.sqrt(self.sq_sum), self.f0)

    def observe(self, k: int, t: float) -> None:
        """Read the state, check it for divergence, and compute the model terms (with the held
        step's torques when the balance controller holds this step) and the stance terms."""
        q, qd = self.phys.read_state()
        if k % DIVERGENCE_CHECK_STEPS == 0:
            why = self.phys.diverged(qd)
            if why is not None:
                raise DivergenceError(f"{self.rollout.spec.name}: the simulation diverged at "
                                      f"t = {t:.3f} s ({why})")
        active, balance = self.active, self.balance
        held = self.held = active is balance and balance.held_torque_step()
        if held:
            lo, hi, self.clearance, self.code, _cop, self.top = step_model_held(
                q, qd, *self.pargs, balance.qdd, balance.mu, self.neg_limit, self.limit,
                self.tau_held)
            stance = None
            terms = (self.Js, self.pts, self.sole_x)
        else:
            lo, hi, self.clearance = step_model_packed(q, qd, *self.pargs)
            stance = active.stance
            if stance is not None:
                # New arrays for the stance feet only; the full ones stay the model's.
                js, pts, sole, (lo, hi) = stance_terms(self.Js, self.pts, self.sole_x, (lo, hi),
                                                       stance, self.n_feet)
                terms = (js, pts, sole)
            else:
                terms = (self.Js, self.pts, self.sole_x)
        self.lo, self.hi, self.stance, self.obs_terms = lo, hi, stance, (q, qd, *terms)
        self.s = 0.5 * (lo + hi)

    def observation(self) -> Observation:
        q, qd, js, pts, sole = self.obs_terms
        return Observation(q, qd, self.M, self.h, self.c, self.cd, self.A_L, self.A_H, js, pts,
                           sole, (self.lo, self.hi), self.stance)

    def fell_physically(self, t: float) -> bool:
        """The fall rules of the body itself: a body other than a foot on the ground, or the
        CM below FALL_CM_FRACTION of its standing height (the clip ends)."""
        if self.clearance < 0.0:
            physical = "body_contact"
        elif self.c[1] < self.cm_floor:
            physical = "cm_drop"
        else:
            return False
        if self.fall_time is None:
            self._fall(t, physical)
        return True

    def _fall(self, t: float, reason: str) -> None:
        self.fall_time, self.fall_reason = t, reason
        self.direction = fall_direction(self.c, self.cd, self.s)

    def act(self, t: float) -> np.ndarray | None:
        """The active controller's torques; None on a held step (they are in `tau_held`,
        clamped)."""
        if self.held:
            self.balance.held_act(self.code, self.top)
            return None
        return self.active.act(self.observation(), t)

    def loses_balance(self, t: float) -> bool:
        """Whether the balance controller has just lost balance (the fall is recorded)."""
        if self.lost:
            return False
        self.c_ref = self.balance.c_ref
        if self.active.lost is None:
            return False
        self.lost = True
        self._fall(t, f"balance_lost:{self.active.lost}")
        return True

    def hand_over(self, t: float) -> np.ndarray:
        """The fall controller takes over from this step (traces on: the fall is shown)."""
        obs = self.observation()
        self.active = self.rollout.fall_controller
        self.active.reset(obs)
        return self.active.act(obs, t)

    def frame(self, k: int, t: float) -> None:
        if self.rec is not None and k % FRAME_EVERY == 0:
            self.rec.frame(t, self.c, self.c_ref, (self.lo, self.hi))

    def step(self, tau: np.ndarray | None, t: float) -> tuple[float, float]:
        """Apply the torques, run the task's events, step the world from t to t + DT; the
        feet's total normal force (N) and CP x (m) of the step."""
        phys, task = self.phys, self.task
        if tau is None:
            phys.add_clamped_torques(self.tau_held.tolist())
        else:
            phys.apply_torques(tau)
        if self.events:
            task.before_step(phys, t)
        phys.make_contacts(self.pts, self.foot_of_point)
        if phys.props:
            phys.collide_props()
        phys.step()
        fy, _fx, cop = phys.contact_forces()
        if self.events:
            task.after_step(phys, t + DT)
            rel = self.releasable
            if (rel is not None and rel.released_at is None and not self.lost
                    and task.interaction_failed(phys, t + DT)):
                rel.release(t + DT)
        phys.clear_contacts()
        return fy, cop

    def measure(self, k: int, t: float, fy: float, cop: float) -> None:
        """The CP error of step k (NaN without ground contact or after balance was lost) into
        the objective's sums and the traces."""
        self.k_done = k + 1
        e = math.nan
        s = self.s
        if fy > MIN_CONTACT_FORCE and not self.lost:
            e = cop - s
            self.sq_sum += e * e
            if abs(e) > self.max_e:  # max(max_e, |e|) without the builtin's call
                self.max_e = abs(e)
            self.contact_steps += 1
        if self.rec is not None:
            self.rec.trace(k, t + DT, cop if fy > MIN_CONTACT_FORCE else math.nan, s, e, self.c,
                           self.c_ref, fy)

    def cut(self, cpu0: float) -> Evaluation:
        """The result of a run stopped by `stop_above`: its objective's lower bound."""
        self.phys.clear_contacts()
        error_norm = math.sqrt(self.sq_sum)
        k_done = self.k_done
        return Evaluation(
            objective=min(error_norm, self.f0), fell=False, fall_time=None, fall_reason=None,
            error_norm=error_norm, max_abs_error=self.max_e, sim_seconds=k_done * DT,
            cpu_seconds=time.process_time() - cpu0, steps=k_done,
            contact_steps=self.contact_steps, cut=True,
        )

    def result(self, cpu0: float) -> Evaluation:
        """The scored clip: the CP error's 2-norm, or the fall penalty, plus the task's."""
        phys, task, r = self.phys, self.task, self.rollout
        phys.clear_contacts()
        error_norm = math.sqrt(self.sq_sum)
        fall_time = self.fall_time
        fell = fall_time is not None
        objective = (fall_penalty(fall_time, r.spec.clip.length, r.steps, r.support_length)
                     if fall_time is not None else error_norm)
        penalty = task.penalty(phys, math.sqrt(r.steps) * r.support_length)
        if penalty:
            objective += penalty
        out_traces = out_frames = None
        if self.rec is not None:
            out_traces, out_frames = self.rec.result(self.k_done)
        k_done = self.k_done
        return Evaluation(
            objective=objective, fell=fell, fall_time=fall_time, fall_reason=self.fall_reason,
            error_norm=error_norm, max_abs_error=self.max_e, sim_seconds=k_done * DT,
            cpu_seconds=time.process_time() - cpu0, steps=k_done,
            contact_steps=self.contact_steps, fall_direction=self.direction,
            task_success=task.success(phys), task_penalty=penalty,
            cmrt_released_at=None if self.releasable is None else self.releasable.released_at,
            traces=out_traces, frames=out_frames,
        )


def evaluate(spec: TaskSpec, cmrt: Cmrt | None = None, traces: bool = False) -> Evaluation:
    """Simulate one clip of `spec` with the CMRT callable (None: no anticipation)."""
    sim = Rollout(spec)
    try:
        return sim.run(cmrt, traces=traces)
    finally:
        sim.close()
