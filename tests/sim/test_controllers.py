"""The controllers: the momentum controller's gain schedules, CoP objective and box; the
protocol both controllers implement."""

from __future__ import annotations

import numpy as np
import pytest

from sim.character import ROOT_DOF
from sim.controllers import (
    Controller,
    ControllerParams,
    FallController,
    GainScheduler,
    MomentumController,
)
from sim.dynamics import GRAVITY, momentum_bias, step_model
from sim.errors import SpecError
from sim.rollout import Rollout
from sim.spec import parse_spec
from sim.trajectory import ease


def test_schedule_scales_and_sets_with_the_ease_weight():
    base = ControllerParams()
    sched = GainScheduler(base, [(1.0, 2.0, 0.2, {"k_t": 2.0}, {"b_p": 3.0})])
    for t in (0.5, 1.0, 2.0, 2.5):  # outside, and the window's ends (weight 0)
        prm = sched(t)
        assert prm.k_t == base.k_t and prm.b_p == 0.0
    mid = sched(1.5)  # weight 1
    assert mid.k_t == pytest.approx(2.0 * base.k_t) and mid.b_p == pytest.approx(3.0)
    w = ease(0.05 / 0.2)[0]  # 0.05 s into the ramp
    ramp = sched(1.05)
    assert ramp.k_t == pytest.approx(base.k_t * (1.0 + w))
    assert ramp.b_p == pytest.approx(3.0 * w)
    assert sched(1.5).b_l == base.b_l  # untouched gains stay
    # four-element entries (no `set`) still work
    assert GainScheduler(base, [(1.0, 2.0, 0.2, {"b_l": 0.5})])(1.5).b_l == pytest.approx(0.5)


def _moving_state(sim: Rollout) -> tuple[np.ndarray, np.ndarray]:
    """The standing pose with the trunk bending forward fast (as mid fast bend)."""
    ch = sim.character
    q = sim.q0.copy()
    qd = np.zeros_like(q)
    qd[ROOT_DOF + ch.hinge_index("waist")] = -7.0  # rad/s
    qd[ROOT_DOF + ch.hinge_index("shoulder_r")] = 7.0
    qd[ROOT_DOF + ch.hinge_index("shoulder_l")] = 7.0
    return q, qd


def test_cop_objective_brings_the_planned_cop_to_the_support_centre():
    """At a fast-bending state, the CoP implied by the QP's qdd* with the velocity-product
    terms (what ODE then measures, docs/physics.md) is nearer the support centre with b_p > 0
    than without, and nearer still with a larger b_p."""
    spec = parse_spec({"name": "b", "clip": {"preparation": 0.2, "duration": 0.4, "decay": 0.2},
                       "task": {"type": "pose_change", "target": {"waist": -90}}})
    sim = Rollout(spec)
    try:
        a = sim.arrays
        q, qd = _moving_state(sim)
        (M, h, c, cd, A_L, A_H, Js, pts, sole_x, lo, hi, _cl) = step_model(
            q, qd, *a.args(), a.feet, a.sole_local, a.heel_local, a.toe_local, a.point_body,
            a.point_local, a.point_radius)
        bias = momentum_bias(q, qd, a.parent, a.a_par, a.a_chi, a.mass, a.feet, a.sole_local)
        m = sim.character.total_mass
        centre = 0.5 * (lo + hi)

        def planned_cop(b_p: float) -> float:
            sim.controller.schedule = GainScheduler(ControllerParams(b_p=b_p), [])
            qdd = sim.controller.solve(0.3, q, qd, c, cd, A_L, A_H, Js, (lo, hi),
                                       (centre, 0.0), (0.0, 0.0), lambda: bias)
            f = A_L @ qdd + bias[0] + np.array([0.0, m * GRAVITY])
            hdot = A_H @ qdd + bias[1]
            # the feet stay planted to first order: J_s qdd + b_S = 0 with the bias
            if b_p:
                np.testing.assert_allclose(Js @ qdd, -bias[2], atol=1e-4)
            return c[0] + (hdot - c[1] * f[0]) / f[1] - centre

        off, on, strong = (abs(planned_cop(b)) for b in (0.0, 1.0, 10.0))
        print(f"planned |CoP - centre|: b_p 0: {off:.3f} m, 1: {on:.3f} m, 10: {strong:.3f} m")
        assert strong < on < off
    finally:
        sim.close()


def _bend_state_model(sim: Rollout, qd_scale: float = 1.0):
    a = sim.arrays
    q, qd = _moving_state(sim)
    qd = qd * qd_scale
    model = step_model(q, qd, *a.args(), a.feet, a.sole_local, a.heel_local, a.toe_local,
                       a.point_body, a.point_local, a.point_radius)
    bias = momentum_bias(q, qd, a.parent, a.a_par, a.a_chi, a.mass, a.feet, a.sole_local)
    return q, qd, model, bias


def _bend_sim() -> Rollout:
    return Rollout(parse_spec({"name": "b",
                               "clip": {"preparation": 0.2, "duration": 0.4, "decay": 0.2},
                               "task": {"type": "pose_change", "target": {"waist": -90}}}))


def _plan(sim: Rollout, prm: ControllerParams, q, qd, model, bias, t: float = 0.3):
    """qdd* for `prm` at the state at time t, and the CoP it implies with the velocity terms."""
    (M, h, c, cd, A_L, A_H, Js, pts, sole_x, lo, hi, _cl) = model
    m = sim.character.total_mass
    sim.controller.schedule = GainScheduler(prm, [])
    qdd = sim.controller.solve(t, q, qd, c, cd, A_L, A_H, Js, (lo, hi),
                               (0.5 * (lo + hi), 0.0), (0.0, 0.0), lambda: bias).copy()
    f = A_L @ qdd + bias[0] + np.array([0.0, m * GRAVITY])
    hdot = A_H @ qdd + bias[1]
    return qdd, c[0] + (hdot - c[1] * f[0]) / f[1], (lo, hi)


def test_cop_box_keeps_the_planned_cop_inside_the_support():
    """Mid fast bend the plain QP plans a CoP far outside the foot (the trunk's reaction,
    docs/physics.md); with cop_box the plan's CoP, velocity terms included, lies on the box's
    edge, the feet stay planted to first order, and a wider margin moves it further in."""
    sim = _bend_sim()
    try:
        q, qd, model, bias = _bend_state_model(sim)
        Js = model[6]
        _, free, (lo, hi) = _plan(sim, ControllerParams(), q, qd, model, bias)
        assert not lo <= free <= hi, (lo, free, hi)
        edges = []
        for box in (0.02, 0.05):
            qdd, cop, _ = _plan(sim, ControllerParams(cop_box=box), q, qd, model, bias)
            np.testing.assert_allclose(Js @ qdd, -bias[2], atol=1e-4)
            assert lo + box - 1e-6 <= cop <= hi - box + 1e-6
            edge = lo + box if free < lo else hi - box
            assert cop == pytest.approx(edge, abs=1e-6)  # active: on the bound, not beyond
            edges.append(cop)
        print(f"planned CoP: free {free:.3f} m, box 0.02: {edges[0]:.3f}, 0.05: {edges[1]:.3f}"
              f" (support {lo:.3f}..{hi:.3f})")
    finally:
        sim.close()


def test_cop_box_is_inactive_while_the_plan_is_inside():
    """Standing still before the bend (no velocity terms), the plain plan's CoP is near the
    support centre: the box changes nothing, so it does not take the CM's feedback away as
    the CoP objective does."""
    sim = _bend_sim()
    try:
        q, qd, model, bias = _bend_state_model(sim, qd_scale=0.0)
        plain, cop, (lo, hi) = _plan(sim, ControllerParams(), q, qd, model, bias, t=0.05)
        boxed, _, _ = _plan(sim, ControllerParams(cop_box=0.05), q, qd, model, bias, t=0.05)
        assert lo + 0.05 < cop < hi - 0.05
        np.testing.assert_allclose(boxed, plain, rtol=0, atol=1e-12)
    finally:
        sim.close()


def test_cop_box_too_wide_is_a_spec_error():
    """Checked when the spec is parsed (once, by the spec model), not when it is simulated."""
    with pytest.raises(SpecError, match=r"schedule\.0\.set\.cop_box: must be below half"):
        parse_spec({"name": "b", "clip": {"preparation": 0.2, "duration": 0.4, "decay": 0.2},
                       "task": {"type": "pose_change", "target": {"waist": -90}},
                       "schedule": [{"set": {"cop_box": 0.2}}]})


def test_both_controllers_follow_the_protocol():
    sim = _bend_sim()
    try:
        for ctl in (sim.controller, sim.fall_controller):
            assert isinstance(ctl, MomentumController | FallController)
            proto: Controller = ctl  # the static protocol; the run-time contract below
            proto.reset(None)
            assert proto.lost is None
    finally:
        sim.close()


def test_tracking_weights_come_from_the_character_file():
    ch = _bend_sim().character
    w = ControllerParams().weight_vector(ch)
    np.testing.assert_array_equal(w, ch.tracking_weights)
    # An override by joint name replaces only that joint's weight.
    name = ch.hinge_names[0]
    w2 = ControllerParams(weights={name: 0.7}).weight_vector(ch)
    assert w2[0] == 0.7 and np.array_equal(w2[1:], ch.tracking_weights[1:])
