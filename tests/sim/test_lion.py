"""The lion (sim/data/lion.yaml): a 25-DOF, 180 kg character loaded by the same loader as the
humanoid, whose model agrees with ODE's bodies and which balances under the default controller.

The model-vs-ODE contract (masses, CoM, mass matrix, accelerations, momenta) runs over every
character file in tests/sim/test_dynamics.py; here: the file itself and balance under the
default controller, with the humanoid's push scaled to the lion's mass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.character import load_character
from sim.rollout import Rollout
from sim.spec import parse_spec

LION_MASS = 180.0  # kg, the paper's lion
LION_HINGES = 22  # 25 DOF - 3 root
#: The humanoid's push (100 N x 0.2 s on the trunk, tests/sim/test_rollout.py) times 180 / 70.
HUMANOID_PUSH_N, HUMANOID_MASS = 100.0, 70.0
LION_PUSH_N = HUMANOID_PUSH_N * LION_MASS / HUMANOID_MASS


@pytest.fixture(scope="module")
def lion():
    return load_character("lion")


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
