"""The rollout: one task spec simulated under the balance controller, measured, and scored.

`Rollout(spec)` builds the character, the task, the physics (with the task's props) and the
controllers once; `run(cmrt)` resets them and simulates the clip (preparation + task + decay)
at 1 ms steps. The loop only coordinates, as dm_control's does: observe (state and model
terms, the body's fall rules), act (the active controller's torques), step the physics (task
events, contacts, ODE), record (the CP error, traces), check the task.

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
from sim.clip_result import Evaluation
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
        # (`PackedModel`: the constants in three arrays and the model terms' outputs as views
        # of one buffer, so that the one compiled call per step unboxes 6 arguments, not 24.)
        self.pack = PackedModel(self.arrays, ch.ndof)

    def run(self, cmrt: Cmrt | None = None, traces: bool = False,
            stop_above: Callable[[], float] | None = None) -> Evaluation:
        """Simulate the clip with the CMRT (None: no anticipation) and score it.

        stop_above: read every CUT_CHECK_STEPS steps, a bound b (inf: none); once the
        objective's lower bound min(sqrt(running sum of e^2), F0) exceeds b the run stops and
        returns that lower bound as its objective with `cut=True` (`optim.rankcut` uses it for
        the candidate that already ranks last). Every other run is unchanged bit for bit."""
        cpu0 = time.process_time()
        clip = _Clip(self, cmrt, traces)
        cut = clip.steps(stop_above)
        return clip.cut(cpu0) if cut else clip.result(cpu0)

    def close(self) -> None:
        self.physics.close()


class _Clip:
    """One run of a `Rollout`. Its loop (`steps`) reads as dm_control's: observe (`_observe`:
    the state, the model terms, the body's own fall rules), act (`_act`: the active
    controller's torques applied; its fall rule and the hand-over to the fall controller),
    step the physics (`_step_physics`: the task's events, contacts, ODE, contact feedback),
    record (`_record`: the CP error, and the traces and frames when on: `Recorder`) and check
    the task (`_check_task`: a failed interaction releases the CMRT). Then the scores
    (`result`, or `cut` for a run stopped by its bound).

    Everything a step reads that does not change during the run (bound methods, the model's
    arrays, limits) is looked up once here, not at every step."""

    def __init__(self, rollout: Rollout, cmrt: Cmrt | None, traces: bool):
        self.rollout = rollout
        phys, task = rollout.physics, rollout.task
        self.phys, self.task = phys, task
        phys.reset(rollout.q0)
        task.reset(phys)
        self.balance = self.active = balance = rollout.controller
        # Only a task that can report a failed interaction gets the wrapper: every other clip
        # hands the controller the CMRT itself.
        self.releasable = (ReleasableCmrt(cmrt, RELEASE_TIME) if cmrt is not None and task.events
                           and task.reports_failure else None)
        balance.reset(None, self.releasable or cmrt)
        self.rec = Recorder(rollout.steps, phys) if traces else None
        self.sq_sum = 0.0
        self.max_e = 0.0
        self.contact_steps = 0
        self.k_done = 0
        self.lost = False  # the balance controller lost balance (traces on: the fall goes on)
        self.fall_time: float | None = None
        self.fall_reason: str | None = None
        self.direction: str | None = None
        #: The CM reference the recording shows (kept up to date only when recording).
        self.c_ref = (rollout.cm0[0], 0.0)
        # Lower bound of the objective at any point of the clip: the running error norm grows
        # (float sums of squares and sqrt are monotone, task penalties are >= 0), and a later
        # fall scores at least F0 = sqrt(steps) x support length.
        self.f0 = math.sqrt(rollout.steps) * rollout.support_length
        self._hoist(rollout)

    def _hoist(self, rollout: Rollout) -> None:
        """What every step reads: the model's output arrays (`PackedModel`: the model terms
        are written into them every step, so the Observation's arrays hold this step's values
        only, as q and qd do), the physics' and controllers' bound methods, the limits."""
        phys, balance, ch = self.phys, self.balance, rollout.character
        (self._M, self._h, self._c, self._cd, self._A_L, self._A_H, self._Js, self._pts,
         self._sole_x) = rollout.pack.arrays()
        self._pargs = rollout.pack.args()
        self._q, self._qd = phys.q, phys.qd  # the arrays `read_state` writes
        self._foot_of_point = np.repeat(ch.feet, 2).tolist()
        self._n_feet = len(ch.feet)
        self._cm_floor = FALL_CM_FRACTION * rollout.cm0[1]
        self._events = self.task.events
        self._has_props = bool(phys.props)
        self._read_state = phys.read_state
        self._apply_torques, self._add_clamped = phys.apply_torques, phys.add_clamped_torques
        self._make_contacts, self._world_step = phys.make_contacts, phys.step
        self._contact_forces, self._clear_contacts = phys.contact_forces, phys.clear_contacts
        # Steps between QP solves: the model terms, the held accelerations' inverse dynamics
        # and the torque clamp in one compiled call (`step_model_held`), when the balance
        # controller offers them (`Controller.held_torque_step`); the same torques and
        # judgement as its `act`, bit for bit.
        self._held_step, self._held_act = balance.held_torque_step, balance.held_act
        self._mu = balance.mu
        self._neg_limit, self._limit = phys.torque_bounds
        self._tau_held = np.empty(len(self._limit))
        self._held: tuple[int, float] | None = None  # this step's (wrench code, top) if held
        self._obs: Observation | None = None  # this step's observation if not held
        self._support = (0.0, 0.0)  # this step's support edges (stance feet)

    def steps(self, stop_above: Callable[[], float] | None) -> bool:
        """Simulate the clip's steps: observe, act, step the physics, record, check the task.
        True when `stop_above` cut the run."""
        observe, act, step_physics, record = (self._observe, self._act, self._step_physics,
                                              self._record)
        check_task = self._check_task if self.releasable is not None else None
        cut_due = self._cut_rule(stop_above) if stop_above is not None else None
        rec = self.rec
        n = self.rollout.steps
        for k in range(n):
            t = k * DT
            if cut_due is not None and k % CUT_CHECK_STEPS == 0 and cut_due():
                self.k_done = k
                return True
            s = observe(k, t)
            if s is None or not act(t, s):  # a fall ends the clip
                break
            if rec is not None and k % FRAME_EVERY == 0:  # the state before this step
                rec.frame(t, self._c, self.c_ref, self._support)
            fy, cop = step_physics(t)
            record(k, t + DT, fy, cop, s)
            if check_task is not None:
                check_task(t + DT)
        else:
            k = n
        self.k_done = k
        return False

    def _cut_rule(self, stop_above: Callable[[], float]) -> Callable[[], bool]:
        """Whether to stop now: the objective's lower bound above the bound `stop_above`
        reads (never once balance is lost)."""
        f0 = self.f0

        def due() -> bool:
            return not self.lost and min(math.sqrt(self.sq_sum), f0) > stop_above()

        return due

    def _observe(self, k: int, t: float) -> float | None:
        """Observe at t: the state read from ODE (checked for divergence every
        DIVERGENCE_CHECK_STEPS steps) and the model terms; on a held step also its clamped
        torques (`step_model_held`). The support centre (of the stance feet), or None when
        the body's own fall rules (a body on the ground, the CM dropped) end the clip."""
        q, qd = self._read_state()
        if k % DIVERGENCE_CHECK_STEPS == 0:
            self._check_divergence(qd, t)
        if self.active is self.balance and self._held_step():
            lo, hi, clearance, code, _cop, top = step_model_held(
                q, qd, *self._pargs, self.balance.qdd, self._mu, self._neg_limit, self._limit,
                self._tau_held)
            self._held = (code, top)
            self._support = support = (lo, hi)
        else:
            lo, hi, clearance = step_model_packed(q, qd, *self._pargs)
            self._held = None
            self._obs = obs = self._observation((lo, hi), self.active.stance)
            self._support = support = obs.support
        s = 0.5 * (support[0] + support[1])
        if clearance < 0.0 or self._c[1] < self._cm_floor:
            if self.fall_time is None:
                self._fall(t, "body_contact" if clearance < 0.0 else "cm_drop", s)
            return None
        return s

    def _observation(self, support: tuple[float, float],
                     stance: tuple[int, ...] | None) -> Observation:
        """This step's Observation; with a stance, its feet's terms only (new arrays: the full
        ones stay the model's)."""
        Js, pts, sole = self._Js, self._pts, self._sole_x
        if stance is not None:
            Js, pts, sole, support = stance_terms(Js, pts, sole, support, stance, self._n_feet)
        return Observation(self._q, self._qd, self._M, self._h, self._c, self._cd, self._A_L,
                           self._A_H, Js, pts, sole, support, stance)

    def _act(self, t: float, s: float) -> bool:
        """Act at t: the active controller's torques (a held step's from `_observe`), applied.
        When the balance controller loses balance, the fall is recorded and, with traces on,
        the fall controller takes over (the fall is shown); without traces the clip ends there
        (False)."""
        held = self._held
        if held is not None:
            self._held_act(*held)
            tau = None  # self._tau_held, clamped
        else:
            tau = self.active.act(self._obs, t)
        if not self.lost:
            if self.rec is not None:
                self.c_ref = self.balance.c_ref
            if self.active.lost is not None:  # the controller's own fall
                self.lost = True
                self._fall(t, f"balance_lost:{self.active.lost}", s)
                if self.rec is None:
                    return False
                tau = self._hand_over(t)
        if tau is None:
            self._add_clamped(self._tau_held.tolist())
        else:
            self._apply_torques(tau)
        return True

    def _step_physics(self, t: float) -> tuple[float, float]:
        """Step the physics from t: the last step's contacts dropped, the task's events, the
        feet's ground contacts and the props' collisions, ODE's step, the feet's contact
        feedback, the task's events after the step (which may read its contacts). The feet's
        total normal force (N) and CP x."""
        phys, task, events = self.phys, self.task, self._events
        self._clear_contacts()
        if events:
            task.before_step(phys, t)
        self._make_contacts(self._pts, self._foot_of_point)
        if self._has_props:
            phys.collide_props()
        self._world_step()
        fy, _fx, cop = self._contact_forces()
        if events:
            task.after_step(phys, t + DT)
        return fy, cop

    def _record(self, k: int, t: float, fy: float, cop: float, s: float) -> None:
        """Record step k, ending at t: its CP error e = cp - s into the objective's sums (NaN
        without ground contact or after balance was lost, and not summed), and the traces when
        on."""
        e = math.nan
        if fy > MIN_CONTACT_FORCE and not self.lost:
            e = cop - s
            self.sq_sum += e * e
            if abs(e) > self.max_e:  # max(max_e, |e|) without the builtin's call
                self.max_e = abs(e)
            self.contact_steps += 1
        if self.rec is not None:
            self.rec.trace(k, t, cop if fy > MIN_CONTACT_FORCE else math.nan, s, e, self._c,
                           self.c_ref, fy)

    def _check_task(self, t: float) -> None:
        """Check the task after the step ending at t: an interaction it reports failed while
        the CMRT is held releases the CMRT."""
        releasable = self.releasable
        if (releasable.released_at is None and not self.lost
                and self.task.interaction_failed(self.phys, t)):
            releasable.release(t)

    def _check_divergence(self, qd: np.ndarray, t: float) -> None:
        why = self.phys.diverged(qd)
        if why is not None:
            raise DivergenceError(f"{self.rollout.spec.name}: the simulation diverged at "
                                  f"t = {t:.3f} s ({why})")

    def _fall(self, t: float, reason: str, s: float) -> None:
        """Record the clip's fall at t: its reason and direction (the CM's capture point's side
        of the support centre s)."""
        self.fall_time, self.fall_reason = t, reason
        self.direction = fall_direction(self._c, self._cd, s)

    def _hand_over(self, t: float) -> np.ndarray:
        """The fall controller takes over from this step (traces on: the fall is shown); its
        torques for this step."""
        obs = self._obs if self._held is None else self._observation(self._support, None)
        fall = self.active = self.rollout.fall_controller
        fall.reset(obs)
        return fall.act(obs, t)

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
