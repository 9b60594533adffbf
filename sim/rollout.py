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
        self.trajectory = PoseTrajectory(self.q0[ROOT_DOF:], self.task.motions,
                                         self.task.tracks)
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
    """One run of a `Rollout`. Its loop (`steps`) reads as dm_control's: observe (the state,
    the model terms, the body's own fall rules), act (the active controller's torques applied;
    its fall rule and the hand-over to the fall controller), step the physics (the task's
    events, contacts, ODE, contact feedback), record (the CP error, and the traces and frames
    when on: `Recorder`) and check the task (a failed interaction releases the CMRT). Then the
    scores (`result`, or `cut` for a run stopped by its bound).

    Each phase is a function made once per run by its builder (`_observer`, `_actor`,
    `_stepper`, `_recorder`, `_task_checker`), which looks up what the phase reads that does
    not change during the run (bound methods, the model's arrays, limits): in the function
    they are closure variables, not attribute look-ups at every step. What passes from one
    phase to the next within a step is the support centre and this step's held-step result,
    observation and support edges (`_held`, `_obs`, `_support`)."""

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
        # The model terms are written into the PackedModel's arrays every step, so the
        # Observation's arrays hold this step's values only, as q and qd (read_state) do.
        (self._M, self._h, self._c, self._cd, self._A_L, self._A_H, self._Js, self._pts,
         self._sole_x) = rollout.pack.arrays()
        self._tau_held = np.empty(len(phys.torque_bounds[1]))  # a held step's clamped torques
        self._held: tuple[int, float] | None = None  # this step's (wrench code, top) if held
        self._obs: Observation | None = None  # this step's observation if not held
        self._support = (0.0, 0.0)  # this step's support edges (stance feet)

    def steps(self, stop_above: Callable[[], float] | None) -> bool:
        """Simulate the clip's steps: observe, act, step the physics, record, check the task.
        True when `stop_above` cut the run."""
        observe, act, step_physics, record = (self._observer(), self._actor(), self._stepper(),
                                              self._recorder())
        check_task = self._task_checker() if self.releasable is not None else None
        cut_due = self._cut_rule(stop_above) if stop_above is not None else None
        rec, c = self.rec, self._c
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
                rec.frame(t, c, self.c_ref, self._support)
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

    def _observer(self) -> Callable[[int, float], float | None]:
        """Observe at t: the state read from ODE (checked for divergence every
        DIVERGENCE_CHECK_STEPS steps) and the model terms (`step_model_packed`); on a held
        step, when the balance controller offers one (`Controller.held_torque_step`), also
        the held accelerations' inverse dynamics and clamped torques in the same compiled call
        (`step_model_held`: the torques and judgement of its `act`, bit for bit). Returns the
        support centre (of the stance feet), or None when the body's own fall rules (a body
        on the ground, the CM dropped) end the clip."""
        clip, phys, balance = self, self.phys, self.balance
        read_state, held_step = phys.read_state, balance.held_torque_step
        pargs = self.rollout.pack.args()
        mu, (neg_limit, limit), tau_held = balance.mu, phys.torque_bounds, self._tau_held
        c, cm_floor = self._c, FALL_CM_FRACTION * self.rollout.cm0[1]
        observation, check_divergence, fall = (self._observation, self._check_divergence,
                                               self._fall)

        def observe(k: int, t: float) -> float | None:
            q, qd = read_state()
            if k % DIVERGENCE_CHECK_STEPS == 0:
                check_divergence(qd, t)
            if clip.active is balance and held_step():
                lo, hi, clearance, code, _cop, top = step_model_held(
                    q, qd, *pargs, balance.qdd, mu, neg_limit, limit, tau_held)
                clip._held = (code, top)
                clip._support = support = (lo, hi)
            else:
                lo, hi, clearance = step_model_packed(q, qd, *pargs)
                clip._held = None
                clip._obs = obs = observation((lo, hi), clip.active.stance)
                clip._support = support = obs.support
            s = 0.5 * (support[0] + support[1])
            if clearance < 0.0 or c[1] < cm_floor:
                if clip.fall_time is None:
                    fall(t, "body_contact" if clearance < 0.0 else "cm_drop", s)
                return None
            return s

        return observe

    def _observation(self, support: tuple[float, float],
                     stance: tuple[int, ...] | None) -> Observation:
        """This step's Observation; with a stance, its feet's terms only (new arrays: the full
        ones stay the model's)."""
        Js, pts, sole = self._Js, self._pts, self._sole_x
        if stance is not None:
            Js, pts, sole, support = stance_terms(Js, pts, sole, support, stance,
                                                  len(self.rollout.character.feet))
        return Observation(self.phys.q, self.phys.qd, self._M, self._h, self._c, self._cd,
                           self._A_L, self._A_H, Js, pts, sole, support, stance)

    def _actor(self) -> Callable[[float, float], bool]:
        """Act at t: the active controller's torques (a held step's from the observation),
        applied. When the balance controller loses balance, the fall is recorded and, with
        traces on, the fall controller takes over (the fall is shown); without traces the
        clip ends there (False)."""
        clip, balance, rec, tau_held = self, self.balance, self.rec, self._tau_held
        held_act = balance.held_act
        apply_torques, add_clamped = self.phys.apply_torques, self.phys.add_clamped_torques

        def act(t: float, s: float) -> bool:
            held = clip._held
            if held is not None:
                held_act(*held)
                tau = None  # tau_held, clamped
            else:
                tau = clip.active.act(clip._obs, t)
            if not clip.lost:
                if rec is not None:
                    clip.c_ref = balance.c_ref
                if clip.active.lost is not None:  # the controller's own fall
                    clip.lost = True
                    clip._fall(t, f"balance_lost:{clip.active.lost}", s)
                    if rec is None:
                        return False
                    tau = clip._hand_over(t)
            if tau is None:
                add_clamped(tau_held.tolist())
            else:
                apply_torques(tau)
            return True

        return act

    def _stepper(self) -> Callable[[float], tuple[float, float]]:
        """Step the physics from t: the last step's contacts dropped, the task's events, the
        feet's ground contacts and the props' collisions, ODE's step, the feet's contact
        feedback, the task's events after the step (which may read its contacts). Returns the
        feet's total normal force (N) and CP x."""
        phys, task = self.phys, self.task
        events, has_props, pts = task.events, bool(phys.props), self._pts
        foot_of_point = np.repeat(self.rollout.character.feet, 2).tolist()
        clear_contacts, make_contacts, collide_props = (phys.clear_contacts, phys.make_contacts,
                                                        phys.collide_props)
        world_step, contact_forces = phys.step, phys.contact_forces
        before_step, after_step = task.before_step, task.after_step

        def step_physics(t: float) -> tuple[float, float]:
            clear_contacts()
            if events:
                before_step(phys, t)
            make_contacts(pts, foot_of_point)
            if has_props:
                collide_props()
            world_step()
            fy, _fx, cop = contact_forces()
            if events:
                after_step(phys, t + DT)
            return fy, cop

        return step_physics

    def _recorder(self) -> Callable[[int, float, float, float, float], None]:
        """Record step k, ending at t: its CP error e = cp - s into the objective's sums (NaN
        without ground contact or after balance was lost, and not summed), and the traces when
        on."""
        clip, rec, c = self, self.rec, self._c

        def record(k: int, t: float, fy: float, cop: float, s: float) -> None:
            e = math.nan
            if fy > MIN_CONTACT_FORCE and not clip.lost:
                e = cop - s
                clip.sq_sum += e * e
                if abs(e) > clip.max_e:  # max(max_e, |e|) without the builtin's call
                    clip.max_e = abs(e)
                clip.contact_steps += 1
            if rec is not None:
                rec.trace(k, t, cop if fy > MIN_CONTACT_FORCE else math.nan, s, e, c,
                          clip.c_ref, fy)

        return record

    def _task_checker(self) -> Callable[[float], None]:
        """Check the task after the step ending at t: an interaction it reports failed while
        the CMRT is held releases the CMRT."""
        clip, releasable, task, phys = self, self.releasable, self.task, self.phys

        def check_task(t: float) -> None:
            if (releasable.released_at is None and not clip.lost
                    and task.interaction_failed(phys, t)):
                releasable.release(t)

        return check_task

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
        out_traces = out_frames = out_states = None
        if self.rec is not None:
            out_traces, out_frames, out_states = self.rec.result(self.k_done)
        k_done = self.k_done
        return Evaluation(
            objective=objective, fell=fell, fall_time=fall_time, fall_reason=self.fall_reason,
            error_norm=error_norm, max_abs_error=self.max_e, sim_seconds=k_done * DT,
            cpu_seconds=time.process_time() - cpu0, steps=k_done,
            contact_steps=self.contact_steps, fall_direction=self.direction,
            task_success=task.success(phys), task_penalty=penalty,
            cmrt_released_at=None if self.releasable is None else self.releasable.released_at,
            traces=out_traces, frames=out_frames, states=out_states,
        )


def evaluate(spec: TaskSpec, cmrt: Cmrt | None = None, traces: bool = False) -> Evaluation:
    """Simulate one clip of `spec` with the CMRT callable (None: no anticipation)."""
    sim = Rollout(spec)
    try:
        return sim.run(cmrt, traces=traces)
    finally:
        sim.close()
