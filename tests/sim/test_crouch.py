"""The vertical CMRT's posture (sim/controllers/crouch.py) against kinematics, and the momentum
controller following it (docs/physics.md, "The vertical CMRT")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.character import ROOT_DOF, load_character
from sim.controllers.crouch import LIMIT_MARGIN, Crouch
from sim.dynamics import ModelArrays, body_point, forward_kinematics
from sim.rollout import Rollout
from sim.spec import parse_spec
from sim.standing import standing_state
from sim.trajectory import ease

#: m: the reached CM height change equals the asked one to this (the secant's tolerance is 1e-9).
HEIGHT_ATOL = 1e-7
#: m, rad: feet and the root's angle stay put to this (the two-link solution is exact).
FEET_ATOL = 1e-9


def _crouched_full(cr: Crouch, q_r: np.ndarray, dy: float) -> tuple[np.ndarray, np.ndarray]:
    """(reference full q, crouched full q): the root moved down by the solved drop."""
    q = cr._pose(q_r)
    off = cr.offsets(q_r, dy)
    qc = q.copy()
    qc[ROOT_DOF:] += off
    qc[1] -= cr._h
    return q, qc


@pytest.mark.parametrize("model", ["humanoid", "lion"])
@pytest.mark.parametrize("dy", [-0.08, -0.03, 0.01])  # within both characters' legs
def test_crouch_changes_the_cm_height_by_dy_with_the_feet_and_trunk_held(model, dy):
    ch = load_character(model)
    a = ModelArrays.from_character(ch)
    q_r = standing_state(ch, a)[ROOT_DOF:]
    q_r[[j for j, n in enumerate(ch.hinge_names) if n.startswith("knee")]] -= math.radians(20)
    q_r[[j for j, n in enumerate(ch.hinge_names) if n.startswith("hip")]] += math.radians(10)
    q_r[[j for j, n in enumerate(ch.hinge_names) if n.startswith("ankle")]] += math.radians(10)
    cr = Crouch(ch, a)
    q, qc = _crouched_full(cr, q_r, dy)
    al0, p0, _ = forward_kinematics(q, a.parent, a.a_par, a.a_chi)
    al1, p1, _ = forward_kinematics(qc, a.parent, a.a_par, a.a_chi)
    m = a.mass / a.mass.sum()
    assert float(m @ p1[:, 1] - m @ p0[:, 1]) == pytest.approx(dy, abs=HEIGHT_ATOL)
    for i, f in enumerate(ch.feet):
        h0 = body_point(al0, p0, int(f), a.heel_local[i])
        h1 = body_point(al1, p1, int(f), a.heel_local[i])
        assert np.abs(h1 - h0).max() < FEET_ATOL
        assert abs(al1[f] - al0[f]) < FEET_ATOL
    assert qc[2] == q[2]  # the trunk keeps its world angle: only the legs' hinges change
    legs = set(cr.hinges.tolist())
    assert all(off == 0.0 for j, off in enumerate(qc[ROOT_DOF:] - q_r) if j not in legs)


def test_crouch_stops_inside_the_leg_limits():
    ch = load_character("lion")
    a = ModelArrays.from_character(ch)
    q_r = standing_state(ch, a)[ROOT_DOF:]
    cr = Crouch(ch, a)
    deep = cr.offsets(q_r, -2.0)  # far more than the legs can give
    hq = (q_r + deep)[cr.hinges]
    lo, hi = ch.limits[cr.hinges, 0], ch.limits[cr.hinges, 1]
    assert np.all(hq >= lo + LIMIT_MARGIN - 1e-9) and np.all(hq <= hi - LIMIT_MARGIN + 1e-9)
    assert np.any(np.isclose(hq, hi - LIMIT_MARGIN, atol=1e-6) | np.isclose(
        hq, lo + LIMIT_MARGIN, atol=1e-6))  # it went as far as one leg hinge allows
    assert np.all(cr.offsets(q_r, 0.0) == 0.0)


#: m: the lion's quiet stance with the vertical CMRT eased to -10 cm must bring its CM within
#: this of 10 cm lower (the momentum objective alone moved it ~1 cm: docs/physics.md).
FOLLOW_ATOL = 0.02
LOWER_BY = -0.10  # m


def test_momentum_controller_follows_a_vertical_cmrt():
    """Quiet stance 2 s, the vertical CMRT eased from 0 to -10 cm over 0.2-1.2 s: the CM comes
    down by 10 cm (within 2 cm) and the lion stands; a zero vertical CMRT is bit for bit the
    run without one."""
    spec = parse_spec({"name": "lower", "character": {"model": "lion"},
                       "clip": {"preparation": 0.0, "duration": 2.0, "decay": 0.0},
                       "task": {"type": "quiet_stance"}, "cmrt": {"vertical": True}})
    sim = Rollout(spec)
    none = sim.run()
    zero = sim.run(lambda t: (0.0, 0.0))
    down = sim.run(lambda t: (0.0, LOWER_BY * ease((t - 0.2) / 1.0)[0]), traces=True)
    sim.close()
    assert zero.objective == none.objective
    cm_y = down.traces.cm[:, 1]
    drop = float(np.mean(cm_y[-200:]) - cm_y[0])
    print(f"CM drop {drop:.4f} m for {LOWER_BY} m; objective {down.objective:.4f}")
    assert not down.fell
    assert drop == pytest.approx(LOWER_BY, abs=FOLLOW_ATOL)
