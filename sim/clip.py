"""Clips: one task spec simulated under the balance controller, measured, and scored.

`Simulator(spec)` builds the character, the ODE world and the controller once; `run(cmrt)`
resets the world and simulates the clip (preparation + task + decay) at 1 ms steps.

Measurements, every step: the centre of pressure p(t) from the contact joints' feedback, the
support centre s(t) (middle of the feet's heel-toe interval), the CP error e = p - s. The
objective is the 2-norm of e over the steps that had ground contact (metres).

A fall ends the clip: a body other than a foot touching the ground, the CM below
FALL_CM_FRACTION of its standing height, or the controller losing balance (its support wrench
stays outside the friction cone or its CoP outside the support for WRENCH_VIOLATION_LIMIT, or
a heel or toe lifts FOOT_LIFT_LIMIT off the ground, or the wrench needs a pulling ground).
Brief violations are tolerated: in ODE a fast bend whose inverse dynamics asked for a CoP beyond
the toe for 60 ms stood (the paper hands over at once, "inevitably going to fall").
The objective of a fall is `fall_penalty`: at least sqrt(steps) x the support length, more than
any non-fall objective can be (|e| never exceeds the support length), and larger the earlier
the fall, so every fall ranks worse than every non-fall and later falls rank better.
With traces on, a clip whose controller lost balance goes on under the fall controller until
a body touches the ground or the CM drops, to show the fall.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from sim.character import ROOT_DOF, Character, load_character
from sim.controller import (
    QP_RATE,
    ControllerParams,
    FallController,
    GainScheduler,
    MomentumController,
    PoseTrajectory,
)
from sim.dynamics import (
    GRAVITY,
    WRENCH_NO_NORMAL_FORCE,
    WRENCH_OK,
    WRENCH_REASONS,
    ModelArrays,
    checked_inverse_dynamics,
    forward_kinematics,
    momentum_bias,
    step_model,
)
from sim.errors import SpecError
from sim.evaluation import Evaluation, Traces
from sim.spec import TaskSpec
from sim.world import CONTACT_SOFT_CFM, DT, FRICTION_MU, WORLD_ERP, World

FALL_CM_FRACTION = 0.6  # a CM below 60 % of its standing height is a fall
#: Narrowest room (m) the CoP box may leave on each side of the support centre.
MIN_COP_BOX_WIDTH = 0.005

#: The controller has lost balance when its support wrench stays inadmissible this long (s)...
WRENCH_VIOLATION_LIMIT = 0.25
#: ... or when a heel or toe has lifted this high (m): the foot is rotating about an edge and
#: the foot-fixed model no longer holds.
FOOT_LIFT_LIMIT = 0.03
MIN_CONTACT_FORCE = 1.0  # N: below this total normal force a step has no CP measurement
CMRT_VELOCITY_STEP = 1e-3  # s, central difference for the CMRT's velocity

Cmrt = Callable[[float], Any]


def standing_state(ch: Character, arrays: ModelArrays) -> np.ndarray:
    """q of the standing pose: feet flat with the right heel where the zero pose has it; with
    `balance_standing`, the body leans at the ankles so the CM is over the support centre."""
    hinge = ch.standing_offsets.copy()
    feet_chains = []
    for f in ch.feet:
        chain, b = [], int(f)
        while b > 0:
            chain.append(b - 1)
            b = int(ch.parent[b])
        feet_chains.append(chain)  # the foot's own hinge first

    def place(phi: float) -> tuple[np.ndarray, float]:
        q = np.zeros(ch.ndof)
        q[2] = phi
        h = hinge.copy()
        for chain in feet_chains:
            own, others = chain[0], chain[1:]
            h[own] = -(phi + sum(h[j] for j in others))  # foot flat on the ground
        q[ROOT_DOF:] = h
        alpha, p, o = forward_kinematics(q, arrays.parent, arrays.a_par, arrays.a_chi)
        f0 = int(ch.feet[0])
        heel = p[f0] + _rot(alpha[f0], arrays.heel_local[0])
        q[:2] += ch.heel0[0] - heel
        alpha, p, o = forward_kinematics(q, arrays.parent, arrays.a_par, arrays.a_chi)
        cx = float((ch.mass * p[:, 0]).sum() / ch.mass.sum())
        centre = 0.5 * (ch.heel0[:, 0].min() + ch.toe0[:, 0].max())
        return q, cx - centre

    if not ch.balance_standing:
        return place(0.0)[0]
    a, b = 0.0, -0.05
    fa, fb = place(a)[1], place(b)[1]
    for _ in range(30):  # secant on the lean angle
        if abs(fb) < 1e-10 or fb == fa:
            break
        a, b, fa = b, b - fb * (b - a) / (fb - fa), fb
        fb = place(b)[1]
    return place(b)[0]


def _rot(a: float, v: np.ndarray) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def fall_penalty(fall_time: float, length: float, steps: int, support_length: float) -> float:
    """Objective of a clip that fell at `fall_time` s of `length`: in (F0, 2 F0], F0 being an
    upper bound of any non-fall objective, sqrt(steps) x support length."""
    f0 = math.sqrt(steps) * support_length
    return f0 * (2.0 - min(max(fall_time / length, 0.0), 1.0))


def _as_pair(value: Any) -> tuple[float, float]:
    if isinstance(value, tuple | list | np.ndarray):
        return float(value[0]), float(value[1]) if len(value) > 1 else 0.0
    return float(value), 0.0


def _check_cop_box(spec: TaskSpec, support_length: float) -> None:
    """The CoP box (controller.cop_box, schedule `set`) must leave room between its bounds."""
    values = [("controller.cop_box", spec.controller.get("cop_box"))] + [
        (f"schedule.{i}.set.cop_box", s.set.get("cop_box")) for i, s in enumerate(spec.schedule)]
    for where, v in values:
        if v is not None and not v < 0.5 * support_length - MIN_COP_BOX_WIDTH:
            raise SpecError(
                f"{where}: must be below half the support length minus {MIN_COP_BOX_WIDTH} m "
                f"({0.5 * support_length - MIN_COP_BOX_WIDTH:.3f} m for this character), "
                f"got {v:g}")


class Simulator:
    """A task spec's world and controller, built once and reset for each run."""

    def __init__(self, spec: TaskSpec):
        self.spec = spec
        ch = load_character(spec.character.model, spec.character.height, spec.character.mass)
        self.character = ch
        self.support_length = float(ch.toe0[:, 0].max() - ch.heel0[:, 0].min())
        _check_cop_box(spec, self.support_length)
        self.arrays = ModelArrays.from_character(ch)
        self.world = World(ch, self.arrays)
        self.q0 = standing_state(ch, self.arrays)
        # Start with the ground contacts already loaded: sink the body by the static
        # penetration of a soft contact, depth = (m g / contacts) / k with the contact
        # stiffness k = ERP / (dt CFM); otherwise the first steps score a loading transient.
        contacts = 2 * len(ch.feet)
        k_contact = WORLD_ERP / (DT * CONTACT_SOFT_CFM)
        self.q0[1] -= ch.total_mass * GRAVITY / contacts / k_contact
        _, p0, _ = forward_kinematics(self.q0, self.arrays.parent, self.arrays.a_par,
                                      self.arrays.a_chi)
        self.cm0 = (ch.mass[:, None] * p0).sum(axis=0) / ch.mass.sum()
        self.params = ControllerParams().with_overrides(dict(spec.controller))
        entries = []
        for s in spec.schedule:
            start, end = spec.schedule_window(s)
            entries.append((start, end, s.ramp, dict(s.scale), dict(s.set)))
        self.schedule = GainScheduler(self.params, entries)
        self.trajectory = PoseTrajectory(self.q0[ROOT_DOF:], self._motions())
        self.controller = MomentumController(ch, self.schedule, self.trajectory)
        self.fall_controller = FallController(ch, DT)
        self.steps = int(round(spec.clip.length / DT))
        self.qp_every = max(1, int(round(1.0 / (QP_RATE * DT))))
        self.push = None
        if spec.push is not None:
            start, dur = spec.push_window()
            sign = 1.0 if spec.push.direction == "forward" else -1.0
            self.push = (ch.body_index(spec.push.body), sign * spec.push.force, start, start + dur)

    def _motions(self) -> list[tuple[float, float, dict[int, float]]]:
        spec, ch = self.spec, self.character

        def offsets(target: dict[str, float]) -> dict[int, float]:
            return {ch.hinge_index(k): math.radians(v) for k, v in target.items()}

        if spec.pose_change is not None:
            return [(spec.clip.task_start, spec.clip.duration, offsets(spec.pose_change.target))]
        return [(m.start, m.duration, offsets(m.target)) for m in spec.motions or []]

    def run(self, cmrt: Cmrt | None = None, traces: bool = False) -> Evaluation:
        """Simulate the clip with the CMRT (None: no anticipation) and score it."""
        cpu0 = time.process_time()
        ch, a, w = self.character, self.arrays, self.world
        n_steps = self.steps
        w.reset(self.q0)
        self.controller.reset()
        foot_of_point = np.repeat(ch.feet, 2).tolist()
        cm_floor = FALL_CM_FRACTION * self.cm0[1]
        rec = traces
        if rec:
            tr = {k: np.full(n_steps, np.nan) for k in ("t", "cp", "support", "error")}
            cm_tr = np.full((n_steps, 2), np.nan)
            ref_tr = np.full((n_steps, 2), np.nan)
        sq_sum = 0.0
        max_e = 0.0
        contact_steps = 0
        fall_time = None
        fall_reason = None
        lost = False
        c_ref = (self.cm0[0], 0.0)
        cmrt_disp = (0.0, 0.0)
        k_done = 0
        violation_steps = 0
        margs = a.args() + (a.feet, a.sole_local, a.heel_local, a.toe_local, a.point_body,
                            a.point_local, a.point_radius)
        for k in range(n_steps):
            t = k * DT
            q, qd = w.read_state()
            (M, h, c, cd, A_L, A_H, Js, pts, sole_x, lo, hi,
             clearance) = step_model(q, qd, *margs)
            s = 0.5 * (lo + hi)
            physical = None
            if clearance < 0.0:
                physical = "body_contact"
            elif c[1] < cm_floor:
                physical = "cm_drop"
            if physical is not None:
                if fall_time is None:
                    fall_time, fall_reason = t, physical
                break
            if not lost:
                if k % self.qp_every == 0:
                    vel = (0.0, 0.0)
                    if cmrt is not None:
                        cmrt_disp = _as_pair(cmrt(t))
                        nxt = _as_pair(cmrt(t + CMRT_VELOCITY_STEP))
                        prv = _as_pair(cmrt(t - CMRT_VELOCITY_STEP))
                        vel = ((nxt[0] - prv[0]) / (2 * CMRT_VELOCITY_STEP), 0.0)
                    c_ref = (s + cmrt_disp[0], cmrt_disp[1])
                    self.controller.solve(
                        t, q, qd, c, cd, A_L, A_H, Js, (lo, hi), c_ref, vel,
                        lambda q=q, qd=qd: momentum_bias(q, qd, a.parent, a.a_par, a.a_chi,
                                                         a.mass, a.feet, a.sole_local))
                tau, code, _cop = checked_inverse_dynamics(M, h, Js, self.controller.qdd,
                                                           sole_x, lo, hi, FRICTION_MU)
                violation_steps = violation_steps + 1 if code != WRENCH_OK else 0
                why = None
                if code == WRENCH_NO_NORMAL_FORCE or violation_steps * DT > WRENCH_VIOLATION_LIMIT:
                    why = WRENCH_REASONS[code]
                elif pts[:, 1].max() > FOOT_LIFT_LIMIT:
                    why = "foot_lift"
                if why is not None:
                    lost = True
                    fall_time, fall_reason = t, f"balance_lost:{why}"
                    if not rec:
                        break
                    self.fall_controller.engage(q[ROOT_DOF:])
            if lost:
                tau = self.fall_controller.torques(q[ROOT_DOF:], qd[ROOT_DOF:])
            w.apply_torques(tau)
            if self.push is not None and self.push[2] <= t < self.push[3]:
                w.add_force(self.push[0], self.push[1])
            w.make_contacts(pts, foot_of_point)
            w.step()
            fy, _fx, cop = w.contact_forces()
            w.clear_contacts()
            k_done = k + 1
            e = math.nan
            if fy > MIN_CONTACT_FORCE and not lost:
                e = cop - s
                sq_sum += e * e
                max_e = max(max_e, abs(e))
                contact_steps += 1
            if rec:
                tr["t"][k] = t + DT
                tr["cp"][k] = cop if fy > MIN_CONTACT_FORCE else math.nan
                tr["support"][k] = s
                tr["error"][k] = e
                cm_tr[k] = c
                ref_tr[k] = (c_ref[0], c[1] + c_ref[1])
        w.clear_contacts()
        error_norm = math.sqrt(sq_sum)
        fell = fall_time is not None
        objective = (fall_penalty(fall_time, self.spec.clip.length, n_steps, self.support_length)
                     if fell else error_norm)
        out_traces = None
        if rec:
            n = k_done
            out_traces = Traces(t=tr["t"][:n], cp=tr["cp"][:n], support=tr["support"][:n],
                                cm=cm_tr[:n], cm_ref=ref_tr[:n], error=tr["error"][:n])
        return Evaluation(
            objective=objective, fell=fell, fall_time=fall_time, fall_reason=fall_reason,
            error_norm=error_norm, max_abs_error=max_e, sim_seconds=k_done * DT,
            cpu_seconds=time.process_time() - cpu0, steps=k_done, contact_steps=contact_steps,
            traces=out_traces,
        )

    def close(self) -> None:
        self.world.close()


def evaluate(spec: TaskSpec, cmrt: Cmrt | None = None, traces: bool = False) -> Evaluation:
    """Simulate one clip of `spec` with the CMRT callable (None: no anticipation)."""
    sim = Simulator(spec)
    try:
        return sim.run(cmrt, traces=traces)
    finally:
        sim.close()
