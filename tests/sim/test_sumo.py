"""The sumo wrestler's data (sim/data/sumo.yaml): its file, quiet stance for 10 s and the
humanoid's push scaled to its mass, under the default controller (no per-character gain). The
model-vs-ODE contract (masses, CoM, mass matrix, accelerations, momenta) runs over every
character file in tests/sim/test_dynamics.py."""

from __future__ import annotations

import numpy as np
import pytest

from sim.character import load_character
from sim.dynamics import ModelArrays, forward_kinematics
from sim.rollout import Rollout
from sim.spec import parse_spec
from sim.standing import standing_state

MODEL = "sumo"
MASS = 180.0  # kg, paper 6.1.6
HEIGHT = 1.82  # m, the file's reference
#: The humanoid's survived push (100 N for 0.2 s on the trunk) scaled by mass / 70 kg.
PUSH_N = 100.0 * MASS / 70.0


@pytest.fixture(scope="module")
def ch():
    return load_character(MODEL)


@pytest.fixture(scope="module")
def arrays(ch):
    return ModelArrays.from_character(ch)


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
