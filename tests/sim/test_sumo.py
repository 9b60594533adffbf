"""The sumo wrestler's data (sim/data/sumo.yaml): mass matrix and CoM from its file against
ODE's bodies, quiet stance for 10 s and the humanoid's push scaled to its mass, under the
default controller (no per-character gain)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.character import ROOT_DOF, load_character
from sim.dynamics import ModelArrays, dynamics, forward_kinematics
from sim.physics import DT, Physics
from sim.rollout import Rollout, standing_state
from sim.spec import parse_spec

MODEL = "sumo"
MASS = 180.0  # kg, paper 6.1.6
HEIGHT = 1.82  # m, the file's reference
#: The humanoid's survived push (100 N for 0.2 s on the trunk) scaled by mass / 70 kg.
PUSH_N = 100.0 * MASS / 70.0
FLIGHT_HEIGHT = 5.0  # m: free-floating states, far from the ground


@pytest.fixture(scope="module")
def ch():
    return load_character(MODEL)


@pytest.fixture(scope="module")
def arrays(ch):
    return ModelArrays.from_character(ch)


@pytest.fixture()
def world(ch, arrays):
    w = Physics(ch, arrays)
    yield w
    w.close()


def random_state(ch, rng, speed):
    lo, hi = ch.limits[:, 0], ch.limits[:, 1]
    q = np.zeros(ch.ndof)
    q[0] = rng.uniform(-0.5, 0.5)
    q[1] = FLIGHT_HEIGHT
    q[2] = rng.uniform(-0.6, 0.6)
    q[ROOT_DOF:] = lo + (hi - lo) * rng.uniform(0.25, 0.75, ch.n_hinges)
    return q, rng.uniform(-speed, speed, ch.ndof)


def test_file_totals_and_heavier_trunk_and_thighs(ch):
    """180 kg, 1.82 m; trunk and thighs heavier than the humanoid scaled to 180 kg."""
    assert ch.total_mass == pytest.approx(MASS, abs=1e-9)
    assert ch.height == HEIGHT
    top = ch.point0[:, 1] + ch.point_radius
    assert top.max() == pytest.approx(HEIGHT, abs=1e-12)
    scaled = load_character("humanoid", HEIGHT, MASS)
    assert scaled.hinge_names == ch.hinge_names and scaled.body_names == ch.body_names
    for seg in ("trunk", "thigh_r", "thigh_l"):
        b = ch.body_index(seg)
        assert ch.mass[b] > scaled.mass[b]
        assert ch.inertia[b] > scaled.inertia[b]  # deeper segments


def test_spec_character_defaults_to_the_file_reference():
    """`character: {model: sumo}` is the file's 1.82 m / 180 kg, not the humanoid's 1.75 / 70;
    a height or mass given still scales it."""
    base = {"name": "s", "task": {"type": "quiet_stance"},
            "clip": {"preparation": 0.0, "duration": 1.0, "decay": 0.0}}
    spec = parse_spec({**base, "character": {"model": MODEL}})
    assert (spec.character.height, spec.character.mass) == (HEIGHT, MASS)
    assert spec.load_character().total_mass == pytest.approx(MASS)
    light = parse_spec({**base, "character": {"model": MODEL, "mass": 120.0}})
    assert (light.character.height, light.character.mass) == (HEIGHT, 120.0)
    assert light.load_character().total_mass == pytest.approx(120.0)
    default = parse_spec(base)
    assert (default.character.height, default.character.mass) == (1.75, 70.0)


def test_ode_bodies_carry_the_file_mass_and_com(ch, arrays, world):
    """ODE's bodies have the file's masses and inertias; the model's CoM (sum m_i p_i / m) is
    the mass-weighted mean of ODE's body positions to round-off, in random states."""
    for b, body in enumerate(world.bodies):
        m = body.getMass()
        assert m.mass == pytest.approx(ch.mass[b], rel=1e-12)
        assert m.I[2][2] == pytest.approx(ch.inertia[b], rel=1e-12)
    rng = np.random.default_rng(5)
    for _ in range(10):
        q, qd = random_state(ch, rng, 1.0)
        world.reset(q, qd)
        c_model = dynamics(q, qd, *arrays.args())[6]
        pos = np.array([body.getPosition()[:2] for body in world.bodies])
        masses = np.array([body.getMass().mass for body in world.bodies])
        c_ode = (masses[:, None] * pos).sum(axis=0) / masses.sum()
        np.testing.assert_allclose(c_model, c_ode, atol=1e-12)


def test_mass_matrix_matches_rigid_ode_at_rest(ch, arrays, world):
    """One step from rest with the hinges made rigid (world CFM 1e-10): ODE's accelerations
    equal M^-1 (tau - G) of the model to the LCP's round-off, pinning M and G (the bound
    and method of the humanoid's test in test_dynamics.py)."""
    world.world.setCFM(1e-10)
    rng = np.random.default_rng(22)
    worst = 0.0
    for _ in range(20):
        q, qd = random_state(ch, rng, 0.0)
        world.reset(q, qd)
        q0, qd0 = (x.copy() for x in world.read_state())
        tau = rng.uniform(-40.0, 40.0, ch.n_hinges)
        M, h, *_ = dynamics(q0, qd0, *arrays.args())
        rhs = -h
        rhs[ROOT_DOF:] += tau
        qdd_model = np.linalg.solve(M, rhs)
        world.apply_torques(tau)
        world.step()
        qdd_ode = (world.read_state()[1] - qd0) / DT
        worst = max(worst, np.linalg.norm(qdd_ode - qdd_model) / np.linalg.norm(qdd_model))
    print(f"sumo, rigid ODE at rest: max rel error {worst:.2e}")
    assert worst < 1e-5
    # M itself: symmetric, positive definite, M[:2, :2] = m I.
    M = dynamics(q0, qd0, *arrays.args())[0]
    np.testing.assert_array_equal(M, M.T)
    assert np.linalg.eigvalsh(M).min() > 0.0
    np.testing.assert_allclose(M[:2, :2], MASS * np.eye(2), rtol=1e-12)


def test_standing_pose_is_balanced(ch, arrays):
    q = standing_state(ch, arrays)
    _, p, _ = forward_kinematics(q, arrays.parent, arrays.a_par, arrays.a_chi)
    cx = float((ch.mass * p[:, 0]).sum() / MASS)
    centre = 0.5 * (ch.heel0[:, 0].min() + ch.toe0[:, 0].max())
    assert cx == pytest.approx(centre, abs=1e-9)


def _spec(task: dict, preparation: float, duration: float, decay: float):
    return parse_spec({"name": "sumo_check", "character": {"model": MODEL}, "task": task,
                       "clip": {"preparation": preparation, "duration": duration,
                                "decay": decay}})


def test_stands_10s():
    sim = Rollout(_spec({"type": "quiet_stance"}, 0.0, 10.0, 0.0))
    ev = sim.run(traces=True)
    sim.close()
    tr = ev.traces
    offset = float(tr.cm[-1, 0] - tr.support[-1])
    print(f"sumo quiet stance: objective {ev.objective:.4f}, max |e| "
          f"{ev.max_abs_error * 1e3:.2f} mm, CM - support centre at 10 s {offset * 1e3:.2f} mm")
    assert not ev.fell, ev.fall_reason
    assert ev.steps == ev.contact_steps == 10_000
    assert abs(offset) < 0.01
    assert np.max(np.abs(tr.error[100:])) < 0.01


@pytest.mark.parametrize("direction", ["forward", "backward"])
def test_survives_the_scaled_push(direction):
    """257 N for 0.2 s on the trunk, both ways: stands, and the CM comes back over the
    support within a centimetre; the CP never leaves the feet."""
    spec = _spec({"type": "push", "force": PUSH_N, "direction": direction, "body": "trunk"},
                 1.0, 0.2, 1.8)
    sim = Rollout(spec)
    ev = sim.run(traces=True)
    sim.close()
    tr = ev.traces
    sign = 1.0 if direction == "forward" else -1.0
    during = (tr.t > 1.0) & (tr.t <= 1.3)
    print(f"sumo push {direction} {PUSH_N:.1f} N: objective {ev.objective:.3f}, max |e| "
          f"{ev.max_abs_error * 1e2:.2f} cm")
    assert not ev.fell, ev.fall_reason
    assert ev.steps == 3000
    assert sign * np.nanmean(tr.error[during]) > 0.0  # the CP goes the push's way
    assert abs(tr.cm[-1, 0] - tr.support[-1]) < 0.01
    assert ev.max_abs_error <= sim.support_length / 2 + 1e-6
