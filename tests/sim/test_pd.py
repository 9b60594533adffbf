"""The PD servos (sim.controllers.pd): spec blocks, the world-space lift against a chain
computed by hand, torque signs, the stable-PD step, the root's propagation to the feet,
determinism, the quiet stance and the CMRT's lean."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from sim.character import ROOT_DOF
from sim.controllers.base import Observation
from sim.controllers.pd import (
    CONSTRAINT_REGULARISATION,
    PdParentConfig,
    PdServo,
    PdWorldConfig,
)
from sim.controllers.registry import CONTROLLER_TYPES
from sim.dynamics import step_model
from sim.errors import SpecError
from sim.rollout import Rollout
from sim.spec import parse_spec
from sim.trajectory import ease

EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"


def _example(name: str, controller=None, **changes) -> dict:
    d = yaml.safe_load((EXAMPLES_DIR / f"{name}.yaml").read_text())
    if controller is not None:
        d["controller"] = controller
    d.update(changes)
    return d


def _quiet(controller, seconds: float = 1.0):
    clip = {"preparation": 0.0, "duration": seconds, "decay": 0.0}
    return parse_spec(_example("quiet_stance", controller, clip=clip))


# ---- the spec union --------------------------------------------------------------------
def test_each_type_parses_and_round_trips():
    assert CONTROLLER_TYPES["pd_parent"] is PdParentConfig
    assert CONTROLLER_TYPES["pd_world"] is PdWorldConfig
    for block in ({"type": "pd_parent"}, {"type": "pd_parent", "k1": 50.0, "k2": 5.0},
                  {"type": "pd_world"}, {"type": "pd_world", "root": "person", "delta": 0.02}):
        spec = parse_spec(_example("slow_bend", block))
        assert spec.controller.type == block["type"]
        for k, v in block.items():
            assert getattr(spec.controller, k) == v
        assert parse_spec(spec.model_dump(mode="json")) == spec
    world = parse_spec(_example("slow_bend", {"type": "pd_world"})).controller
    assert (world.k1, world.k2, world.root, world.stable) == (100.0, 10.0, "absolute", True)
    assert world.delta == pytest.approx(1.0 / 120.0)


@pytest.mark.parametrize(("name", "block", "changes", "field", "rule"), [
    ("slow_bend", {"type": "pd_wrld"}, {}, "controller.type",
     "controller types are momentum, pd_parent, pd_world"),
    ("slow_bend", {"type": "pd_world", "k1": 0.0}, {}, "controller.k1",
     "must be from 0.001 to 10000 s^-2 per kg m^2"),
    ("slow_bend", {"type": "pd_world", "root": "pelvis"}, {}, "controller.root", "absolute"),
    ("slow_bend", {"type": "pd_world", "delta": 0.0}, {}, "controller.delta", "0.001"),
    ("slow_bend", {"type": "pd_parent", "delta": 0.01}, {}, "controller.delta", "Extra"),
    ("slow_bend", {"type": "pd_parent", "k_l": 20.0}, {}, "controller.k_l", "Extra"),
    ("fast_bend", {"type": "pd_world"}, {}, "schedule", "apply to the momentum controller"),
    ("slow_bend", {"type": "pd_world"}, {"cmrt": {"vertical": True}}, "cmrt.vertical",
     "horizontal CMRT only"),
])
def test_bad_pd_block_names_field_and_rule(name, block, changes, field, rule):
    with pytest.raises(SpecError) as info:
        parse_spec(_example(name, block, **changes), source="bad.yaml")
    msg = str(info.value)
    assert f"bad.yaml: {field}: " in msg, msg
    assert rule in msg, msg


# ---- the world-space lift ----------------------------------------------------------------
@pytest.fixture(scope="module")
def bend():
    """A slow-bend rollout under pd_world (its controller, trajectory, character)."""
    sim = Rollout(parse_spec(_example("slow_bend", {"type": "pd_world"})))
    yield sim
    sim.close()


def test_desired_world_angles_follow_the_desired_chain_by_hand(bend):
    ch, ctl = bend.character, bend.controller
    t = 1.6  # mid-bend
    th, _, lam = ctl.desired_hinges(t)
    j = {n: th[ch.hinge_index(n)] for n in ch.hinge_names}
    root = bend.q0[2] - lam
    w = ctl.desired_world(t)
    by_hand = {
        "pelvis": root,
        "trunk": root + j["waist"],
        "head": root + j["waist"] + j["neck"],
        "forearm_r": root + j["waist"] + j["shoulder_r"] + j["elbow_r"],
        "shank_l": root + j["hip_l"] + j["knee_l"],
        "foot_r": root + j["hip_r"] + j["knee_r"] + j["ankle_r"],
    }
    for body, angle in by_hand.items():
        assert w[ch.body_index(body)] == pytest.approx(angle, abs=1e-12), body
    # the lean turns every segment above the feet and leaves the feet as the reference has
    # them (flat in the standing pose)
    q_r = bend.trajectory(t)[0]
    unleaned = bend.q0[2] + ctl.lift_matrix @ q_r
    for b in range(ch.n_bodies):
        expected = unleaned[b] if b in ctl.feet else unleaned[b] - lam
        assert w[b] == pytest.approx(expected, abs=1e-12)
    assert w[ch.body_index("foot_r")] == pytest.approx(0.0, abs=1e-9)


def test_the_lift_ignores_the_actual_pose(bend):
    """Absolute: the torques' desired angles do not move with the actual segments; person
    space: the whole desired chain turns with the actual root only."""
    ch, ctl = bend.character, bend.controller
    q = bend.q0.copy()
    q[ROOT_DOF + ch.hinge_index("waist")] -= 0.3
    qd = np.zeros_like(q)
    base = ctl.world_torques(bend.q0, qd, 0.5)
    bent = ctl.world_torques(q, qd, 0.5)
    # the waist bent 0.3 rad forward: the trunk and everything on it is 0.3 rad off its
    # world target, so the waist, neck, shoulders and elbows push back (its descendants too)
    k1 = ctl.K1
    for name in ("waist", "neck", "shoulder_r", "shoulder_l", "elbow_r", "elbow_l"):
        i = ch.hinge_index(name)
        assert bent[i] - base[i] == pytest.approx(0.3 * k1[i], rel=1e-9), name
    for name in ("hip_r", "knee_r", "ankle_r", "hip_l", "knee_l", "ankle_l"):
        i = ch.hinge_index(name)
        assert bent[i] - base[i] == pytest.approx(0.0, abs=1e-9), name
    person = PdServo(ch, bend.arrays, bend.trajectory, bend.q0, "world", root="person")
    tilted = bend.q0.copy()
    tilted[2] += 0.2  # the whole body turned: in person space nothing is off
    assert np.abs(person.world_torques(tilted, qd, 0.5)
                  - person.world_torques(bend.q0, qd, 0.5)).max() < 1e-9


def test_parent_space_torque_sign_on_one_hinge(bend):
    """theta 0.1 rad beyond the target, at rest: u = -K1 0.1 on that hinge only; moving away
    at 1 rad/s adds -K2."""
    ch = bend.character
    ctl = PdServo(ch, bend.arrays, bend.trajectory, bend.q0, "parent")
    i = ch.hinge_index("elbow_r")
    q, qd = bend.q0.copy(), np.zeros(ch.ndof)
    base = ctl.parent_torques(q, qd, 0.0)
    q[ROOT_DOF + i] += 0.1
    qd[ROOT_DOF + i] = 1.0
    diff = ctl.parent_torques(q, qd, 0.0) - base
    assert diff[i] == pytest.approx(-0.1 * ctl.K1[i] - 1.0 * ctl.K2[i], rel=1e-12)
    assert np.abs(np.delete(diff, i)).max() == 0.0
    assert ctl.K1[i] > 0 and ctl.K2[i] > 0


def test_root_torque_reaches_the_ground_through_the_feet(bend):
    """The absolute root's torque, spread over the leg hinges, gives the root +tau, each foot
    -tau / n_f (the ground's share) and every other segment nothing."""
    ch, ctl = bend.character, bend.controller
    u = 1.0 * ctl.root_spread  # hinge torques for tau_root = 1 N m
    net = np.zeros(ch.n_bodies)
    for j, tj in enumerate(u):
        child = j + 1
        net[child] += tj
        net[ch.parent[child]] -= tj
    feet = [int(f) for f in ch.feet]
    assert net[0] == pytest.approx(1.0)
    for f in feet:
        assert net[f] == pytest.approx(-1.0 / len(feet))
    others = [b for b in range(1, ch.n_bodies) if b not in feet]
    assert np.abs(net[others]).max() < 1e-12


def test_stable_torque_is_the_law_at_the_predicted_next_state():
    """tau = the explicit law at (q + dt qd, qd + dt qdd), qdd being what the feet-held model
    (the same regularised KKT system) gives for tau itself: the implicit equation holds to
    rounding."""
    sim = Rollout(_quiet({"type": "pd_parent"}))
    try:
        ctl, ch, a = sim.controller, sim.character, sim.arrays
        rng = np.random.default_rng(3)
        q = sim.q0 + np.concatenate([[0, 0, 0.01], 0.02 * rng.standard_normal(ch.n_hinges)])
        qd = np.concatenate([[0, 0, 0.1], 0.3 * rng.standard_normal(ch.n_hinges)])
        model = step_model(q, qd, *a.args(), a.feet, a.sole_local, a.heel_local, a.toe_local,
                           a.point_body, a.point_local, a.point_radius)
        M, h, c, cd, A_L, A_H, Js, pts, sole_x, lo, hi, _ = model
        obs = Observation(q, qd, M, h, c, cd, A_L, A_H, Js, pts, sole_x, (lo, hi))
        ctl.reset()
        explicit = ctl.parent_torques(q, qd, 0.2)
        explicit[ctl.ankles] += ctl.K2[ctl.ankles] * (ctl.foot_rows @ qd)
        tau = ctl.stable_torques(explicit, obs)
        n, k = ch.ndof, Js.shape[0]
        kkt = np.block([[M, -Js.T], [Js, CONSTRAINT_REGULARISATION * np.eye(k)]])
        rhs = np.concatenate([-h, np.zeros(k)])
        rhs[ROOT_DOF:n] += tau
        qdd = np.linalg.solve(kkt, rhs)[:n]
        dt = ctl.dt
        law = explicit - ctl.B_p @ (dt * qd) - ctl.B_d @ (dt * qdd)
        assert np.abs(law - tau).max() < 1e-6 * max(1.0, np.abs(tau).max())
        assert np.abs(tau - explicit).max() > 1.0  # the prediction matters at these gains
    finally:
        sim.close()


# ---- whole clips -----------------------------------------------------------------------------
def test_quiet_stance_stands_with_pd_world():
    """10 s quiet stance: stands; the PD has no gravity term, so the CM settles a little
    ahead of the support centre (measured 1.77 cm) and stays there."""
    spec = parse_spec(_example("quiet_stance", {"type": "pd_world"}))
    sim = Rollout(spec)
    try:
        e = sim.run(traces=True)
    finally:
        sim.close()
    assert not e.fell and e.sim_seconds == pytest.approx(10.0)
    last = e.traces.error[-1000:]
    assert np.nanmax(np.abs(last)) < 0.03  # inside the 26.6 cm support, settled
    assert np.nanstd(last) < 1e-3


def test_same_spec_same_result():
    spec = parse_spec(_example("push", {"type": "pd_world"}))
    a = Rollout(spec)
    b = Rollout(spec)
    try:
        first, again, other = a.run(), a.run(), b.run()
    finally:
        a.close()
        b.close()
    assert first.objective == again.objective == other.objective
    assert not first.fell


@pytest.mark.parametrize("kind", ["pd_world", "pd_parent"])
def test_a_cmrt_moves_the_cm_by_its_displacement(kind):
    """The CMRT enters as a lean: a displacement eased in over 1 s to +-3 cm moves the
    settled CM forward / backward of where it settles without one, linearly in the
    displacement; by more than the displacement, since a PD without a gravity term also sags
    under the lean's gravity torque (measured 1.48 x for pd_world, 1.39 x for pd_parent)."""
    spec = _quiet({"type": kind}, seconds=3.0)
    sim = Rollout(spec)
    try:
        flat = sim.run(traces=True)
        fwd = sim.run(lambda t: 0.03 * ease(t / 1.0)[0], traces=True)
        back = sim.run(lambda t: -0.03 * ease(t / 1.0)[0], traces=True)
    finally:
        sim.close()
    assert not (flat.fell or fwd.fell or back.fell)
    settled = flat.traces.cm[-500:, 0]
    ahead = float(np.mean(fwd.traces.cm[-500:, 0] - settled))
    behind = float(np.mean(back.traces.cm[-500:, 0] - settled))
    assert 0.03 < ahead < 0.06 and -0.06 < behind < -0.03
    assert ahead == pytest.approx(-behind, rel=0.05)  # linear in the displacement

