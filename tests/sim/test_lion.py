"""The lion (sim/data/lion.yaml): a 25-DOF, 180 kg character loaded by the same loader as the
humanoid, whose model agrees with ODE's bodies and which balances under the default controller.

Model-vs-ODE tests follow tests/sim/test_dynamics.py (free flight 5 m up, hinges in the middle
half of their ranges); the balance tests use the humanoid's push scaled to the lion's mass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.character import ROOT_DOF, load_character
from sim.dynamics import ModelArrays, dynamics, forward_kinematics
from sim.physics import DT, Physics
from sim.rollout import Rollout
from sim.spec import parse_spec

LION_MASS = 180.0  # kg, the paper's lion
LION_HINGES = 22  # 25 DOF - 3 root
FLIGHT_HEIGHT = 5.0  # m
#: The humanoid's push (100 N x 0.2 s on the trunk, tests/sim/test_rollout.py) times 180 / 70.
HUMANOID_PUSH_N, HUMANOID_MASS = 100.0, 70.0
LION_PUSH_N = HUMANOID_PUSH_N * LION_MASS / HUMANOID_MASS


@pytest.fixture(scope="module")
def lion():
    return load_character("lion")


@pytest.fixture(scope="module")
def arrays(lion):
    return ModelArrays.from_character(lion)


@pytest.fixture()
def world(lion, arrays):
    w = Physics(lion, arrays)
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


def test_lion_file_is_a_25_dof_180_kg_character(lion):
    assert lion.ndof == 25 and lion.n_hinges == LION_HINGES
    assert lion.n_bodies == LION_HINGES + 1
    assert lion.total_mass == pytest.approx(LION_MASS, abs=1e-9)
    assert lion.height == pytest.approx(2.28)
    assert len(lion.feet) == 2 and lion.hands == ("paw_r", "paw_l")
    assert lion.body_names[lion.torso] == "chest"


def test_spec_naming_the_lion_gets_its_reference_size():
    spec = parse_spec({"name": "l", "character": {"model": "lion"},
                       "task": {"type": "quiet_stance"}, "clip": {"duration": 1.0}})
    assert spec.character.mass == LION_MASS and spec.character.height == pytest.approx(2.28)
    assert spec.load_character().total_mass == pytest.approx(LION_MASS)
    # The humanoid's default is unchanged, and a given size still scales the file.
    assert parse_spec({"name": "h", "task": {"type": "quiet_stance"},
                       "clip": {"duration": 1.0}}).character.mass == 70.0
    scaled = parse_spec({"name": "l", "character": {"model": "lion", "mass": 150.0},
                         "task": {"type": "quiet_stance"}, "clip": {"duration": 1.0}})
    assert scaled.load_character().total_mass == pytest.approx(150.0)
    assert scaled.character.height == pytest.approx(2.28)


def test_ode_bodies_carry_the_file_masses_and_com(lion, arrays, world):
    """ODE's body masses and inertias are the file's, and the CoM of ODE's bodies after a reset
    to random states equals the model's to round-off (same formulas both sides)."""
    masses = np.array([b.getMass().mass for b in world.bodies])
    inertias = np.array([b.getMass().I[2][2] for b in world.bodies])
    np.testing.assert_allclose(masses, lion.mass, rtol=1e-12)
    np.testing.assert_allclose(inertias, lion.inertia, rtol=1e-12)
    rng = np.random.default_rng(113)
    worst = 0.0
    for _ in range(10):
        q, qd = random_state(lion, rng, 1.0)
        world.reset(q, qd)
        c_model = dynamics(q, qd, *arrays.args())[6]
        pos = np.array([b.getPosition()[:2] for b in world.bodies])
        c_ode = (masses[:, None] * pos).sum(axis=0) / masses.sum()
        worst = max(worst, float(np.linalg.norm(c_model - c_ode)))
        _, p, _ = forward_kinematics(q, arrays.parent, arrays.a_par, arrays.a_chi)
        np.testing.assert_allclose(p, pos, atol=1e-12)
    assert worst < 1e-12


def test_mass_matrix_matches_rigid_ode_at_rest(lion, arrays, world):
    """qdd = M^-1 (S tau - G) against ODE's one-step acceleration with rigid hinges (world CFM
    1e-10) at rest: the humanoid's test_accelerations_match_rigid_ode_at_rest, same bound."""
    world.world.setCFM(1e-10)
    rng = np.random.default_rng(114)
    worst = 0.0
    for _ in range(10):
        q, _ = random_state(lion, rng, 0.0)
        world.reset(q, np.zeros_like(q))
        q0, qd0 = (x.copy() for x in world.read_state())
        tau = rng.uniform(-20.0, 20.0, lion.n_hinges)
        M, h, *_ = dynamics(q0, qd0, *arrays.args())
        rhs = -h
        rhs[ROOT_DOF:] += tau
        qdd_model = np.linalg.solve(M, rhs)
        world.apply_torques(tau)
        world.step()
        qdd_ode = (world.read_state()[1] - qd0) / DT
        worst = max(worst, float(np.linalg.norm(qdd_ode - qdd_model)
                                 / np.linalg.norm(qdd_model)))
    print(f"lion, rigid ODE at rest: max rel qdd error {worst:.2e}")
    assert worst < 1e-5
    np.testing.assert_allclose(M[:2, :2], LION_MASS * np.eye(2), rtol=1e-12)
    assert np.linalg.eigvalsh(M).min() > 0.0


def test_momentum_rows_match_ode_bodies(lion, arrays, world):
    """A_L qd and A_H qd against the momenta summed over ODE's bodies right after a reset."""
    rng = np.random.default_rng(115)
    for _ in range(5):
        q, qd = random_state(lion, rng, 1.0)
        world.reset(q, qd)
        r = dynamics(q, qd, *arrays.args())
        m = lion.mass
        pos = np.array([b.getPosition()[:2] for b in world.bodies])
        vel = np.array([b.getLinearVel()[:2] for b in world.bodies])
        om = np.array([b.getAngularVel()[2] for b in world.bodies])
        c = (m[:, None] * pos).sum(axis=0) / m.sum()
        rel = pos - c
        L = (m[:, None] * vel).sum(axis=0)
        H = float((m * (rel[:, 0] * vel[:, 1] - rel[:, 1] * vel[:, 0])).sum()
                  + (lion.inertia * om).sum())
        np.testing.assert_allclose(r[8] @ qd, L, rtol=1e-10, atol=1e-10 * np.linalg.norm(L))
        assert float(r[9] @ qd) == pytest.approx(H, rel=1e-10)


def _lion_spec(task: dict, duration: float, preparation: float = 0.0, decay: float = 0.0):
    return parse_spec({"name": "lion_balance", "character": {"model": "lion"}, "task": task,
                       "clip": {"preparation": preparation, "duration": duration,
                                "decay": decay}})


def test_lion_stands_10s():
    sim = Rollout(_lion_spec({"type": "quiet_stance"}, 10.0))
    ev = sim.run(traces=True)
    sim.close()
    tr = ev.traces
    offset = float(tr.cm[-1, 0] - tr.support[-1])
    print(f"lion quiet stance: objective {ev.objective:.4f} m, CM - support centre at 10 s "
          f"{offset * 1e3:.3f} mm, max |e| {ev.max_abs_error * 1e2:.2f} cm")
    assert not ev.fell, ev.fall_reason
    assert ev.steps == 10_000 and ev.contact_steps == ev.steps
    assert np.max(np.abs(tr.cm[:, 0] - tr.support)) < 0.01
    assert np.max(np.abs(tr.error[100:])) < 0.01
    assert np.ptp(tr.support) < 1e-3


@pytest.mark.parametrize("direction", ["forward", "backward"])
def test_lion_survives_the_humanoids_push_scaled_to_its_mass(direction):
    """257 N x 0.2 s on the chest (the torso of the file) after 1 s, 1.8 s to recover."""
    spec = _lion_spec({"type": "push", "force": LION_PUSH_N, "direction": direction}, 0.2,
                      preparation=1.0, decay=1.8)
    sim = Rollout(spec)
    ev = sim.run(traces=True)
    sim.close()
    tr = ev.traces
    print(f"lion push {LION_PUSH_N:.1f} N {direction}: objective {ev.objective:.3f}, "
          f"max |e| {ev.max_abs_error * 1e2:.2f} cm")
    assert not ev.fell, ev.fall_reason
    # The push moved the CM the push's way, and by the end it is back over the support.
    sign = 1.0 if direction == "forward" else -1.0
    dev = sign * (tr.cm[:, 0] - tr.support)
    assert dev.max() > 0.01
    assert abs(float(tr.cm[-1, 0] - tr.support[-1])) < 0.02
    assert math.isfinite(ev.objective)
