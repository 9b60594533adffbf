"""sim.physics against physics: props in the plane, their contacts, run-time joints, reset.

Short worlds (a few hundred 1 ms steps), the character far from the props unless a test puts
them together.
"""

from __future__ import annotations

import math

import numpy as np
import ode
import pytest

from sim.character import load_character
from sim.dynamics import GRAVITY, ModelArrays
from sim.errors import SimError
from sim.physics import (
    DT,
    PROP_CHARACTER,
    PROP_GROUND,
    PROP_PROP,
    DivergenceError,
    Physics,
)
from sim.props import Hanging, PropDef
from sim.standing import standing_state

FAR = 20.0  # m: props this far ahead of the character do not touch it


@pytest.fixture(scope="module")
def humanoid():
    ch = load_character()
    return ch, ModelArrays.from_character(ch)


def _physics(humanoid, *props: PropDef) -> Physics:
    ch, arrays = humanoid
    ph = Physics(ch, arrays, props)
    ph.reset(standing_state(ch, arrays))
    return ph


def _energy(ph: Physics) -> float:
    """Kinetic plus gravitational potential energy (J) of every body, prop and link."""
    e = 0.0
    for b in ph._all_bodies():
        m = b.getMass()
        mass, inertia = m.mass, m.I[2][2]
        vx, vy, vz = b.getLinearVel()
        w = b.getAngularVel()
        e += 0.5 * mass * (vx * vx + vy * vy + vz * vz) + 0.5 * inertia * w[2] ** 2
        e += mass * GRAVITY * b.getPosition()[1]
    return e


def _momentum(ph: Physics) -> tuple[float, float, float]:
    """Total linear momentum (kg m/s, x and y) and angular momentum about the world origin
    (kg m^2/s, z) of every body, prop and link."""
    px = py = lz = 0.0
    for b in ph._all_bodies():
        m = b.getMass()
        vx, vy, _ = b.getLinearVel()
        x, y, _ = b.getPosition()
        px += m.mass * vx
        py += m.mass * vy
        lz += m.mass * (x * vy - y * vx) + m.I[2][2] * b.getAngularVel()[2]
    return px, py, lz


def _run(ph: Physics, steps: int, each=None) -> None:
    for k in range(steps):
        ph.collide_props()
        ph.step()
        if each is not None:
            each(k, ph)
        ph.clear_contacts()


def test_dropped_prop_falls_freely(humanoid):
    """Before it lands, a dropped ball follows ODE's semi-implicit Euler exactly
    (y_n = y0 - g dt^2 n (n + 1) / 2) and free fall within g t dt / 2."""
    y0, n = 3.0, 400
    ph = _physics(humanoid, PropDef("ball", "sphere", (0.1,), 7.0, (FAR, y0)))
    try:
        _run(ph, n)
        x, y, a = ph.prop("ball").pose()
        t = n * DT
        assert y == pytest.approx(y0 - GRAVITY * DT * DT * n * (n + 1) / 2, abs=1e-12)
        assert abs(y - (y0 - 0.5 * GRAVITY * t * t)) <= 0.5 * GRAVITY * t * DT + 1e-12
        assert x == FAR and a == 0.0
        vx, vy, vz = ph.prop("ball").body.getLinearVel()
        assert vy == pytest.approx(-GRAVITY * t, rel=1e-12) and vx == 0.0 and vz == 0.0
    finally:
        ph.close()


def test_box_at_rest_on_the_ground_carries_its_weight(humanoid):
    """A 140 kg block standing on the ground: two contacts (the mirrored half of ODE's four
    dropped), their normal forces sum to m g, it does not move."""
    m = 140.0
    ph = _physics(humanoid, PropDef("block", "box", (0.4, 1.6), m, (FAR, 0.8)))
    seen = []
    try:
        _run(ph, 300, lambda k, p: seen.append(p.contact_list()) if k == 299 else None)
        block = [c for c in seen[0] if c.a == "block"]
        assert len(block) == 2 and all(c.kind == PROP_GROUND and c.b is None for c in block)
        assert sum(c.force[1] for c in block) == pytest.approx(m * GRAVITY, rel=1e-3)
        assert abs(sum(c.force[0] for c in block)) < 1e-6
        x, y, a = ph.prop("block").pose()
        assert abs(x - FAR) < 1e-9 and abs(a) < 1e-9 and abs(y - 0.8) < 1e-3
    finally:
        ph.close()


def test_props_stack_and_stay_in_the_plane(humanoid):
    """A spinning box thrown onto another: prop-prop contacts appear, and the free props keep
    z = 0 and a rotation about z only (re-projection after each step)."""
    ph = _physics(humanoid,
                  PropDef("low", "box", (0.6, 0.4), 20.0, (FAR, 0.2)),
                  PropDef("high", "box", (0.3, 0.3), 5.0, (FAR - 0.2, 0.9), angle=0.3,
                          velocity=(0.5, 0.0), angular_velocity=4.0))
    kinds = set()
    try:
        _run(ph, 800, lambda k, p: kinds.update(c.kind for c in p.contact_list()))
        assert PROP_PROP in kinds and PROP_GROUND in kinds
        for name in ("low", "high"):
            body = ph.prop(name).body
            _w, qx, qy, _z = body.getQuaternion()
            assert qx == 0.0 and qy == 0.0
            assert abs(body.getPosition()[2]) < 1e-6
            assert body.getAngularVel()[0] == 0.0 and body.getAngularVel()[1] == 0.0
        assert ph.prop("high").pose()[1] > 0.4  # it rests on the low box, not in it
    finally:
        ph.close()


def test_hanging_bag_at_rest_stays_still(humanoid):
    """A 30 kg bag on a rigid rod and one on a 4-link chain, released at rest straight below
    their anchors: after 1 s neither has moved by more than the joints' softness (micrometres)
    nor gained speed."""
    ph = _physics(humanoid,
                  PropDef("bag", "capsule", (0.15, 0.6), 30.0, (FAR, 1.0),
                          hanging=Hanging((FAR, 2.0))),
                  PropDef("chain_bag", "capsule", (0.15, 0.6), 30.0, (FAR + 2, 1.0),
                          hanging=Hanging((FAR + 2, 2.0), links=4)))
    try:
        _run(ph, 1000)
        for name, x0 in (("bag", FAR), ("chain_bag", FAR + 2)):
            x, y, a = ph.prop(name).pose()
            assert abs(x - x0) < 1e-9 and abs(y - 1.0) < 2e-5 and abs(a) < 1e-9, name
            v = ph.prop(name).body.getLinearVel()
            assert math.hypot(v[0], v[1]) < 1e-4, name
    finally:
        ph.close()


def test_hanging_bag_swings_as_a_pendulum(humanoid):
    """Pushed sideways, the rod-hung bag keeps its distance to the anchor and its energy."""
    length = 1.0
    ph = _physics(humanoid, PropDef("bag", "sphere", (0.1,), 30.0, (FAR, 2.0 - length),
                                    velocity=(1.0, 0.0), hanging=Hanging((FAR, 2.0))))
    try:
        bag = ph.prop("bag")
        m, inertia = 30.0, bag.definition.inertia

        def energy() -> float:
            vx, vy, _ = bag.body.getLinearVel()
            w = bag.body.getAngularVel()[2]
            return 0.5 * m * (vx * vx + vy * vy) + 0.5 * inertia * w * w + \
                m * GRAVITY * bag.body.getPosition()[1]

        e0 = energy()
        _run(ph, 1500)
        x, y, _ = bag.pose()
        assert math.hypot(x - FAR, y - 2.0) == pytest.approx(length, abs=1e-4)
        assert energy() == pytest.approx(e0, rel=2e-3)
    finally:
        ph.close()


def test_hand_geoms_touch_props(humanoid):
    """A ball dropped onto the character's right hand: a prop-character contact on a hand or
    forearm geom, the contact force on the ball points up."""
    ch, arrays = humanoid
    ph = _physics(humanoid, PropDef("ball", "sphere", (0.1,), 1.0, (0.0, 0.0)))
    try:
        hand = ph.geoms[ch.hands[0]]
        hx, hy, _ = hand.getPosition()
        ball = ph.prop("ball")
        ball.body.setPosition((hx, hy + 0.05 + 0.1 + 0.02, 0.0))
        hits = []
        _run(ph, 100, lambda k, p: hits.extend(c for c in p.contact_list()
                                               if c.kind == PROP_CHARACTER))
        assert hits, "the ball never touched the hand"
        assert {c.a for c in hits} == {"ball"}
        assert {c.b for c in hits} <= {"forearm_r", "forearm_l"}
        assert max(c.force[1] for c in hits) > 0.0
    finally:
        ph.close()


def test_attach_and_reset_release_joints_safely(humanoid):
    """attach_prop welds a prop to a body (it then moves with the body); reset drops the weld
    (feedback off first: no abort) and puts the prop back; closing twice is harmless."""
    ch, arrays = humanoid
    ph = _physics(humanoid, PropDef("ball", "sphere", (0.1,), 2.0, (FAR, 1.0)))
    try:
        ball = ph.prop("ball")
        hand_body = ch.body_names[ch.geoms[-1].body]
        ball.body.setPosition(ph.bodies[ch.geoms[-1].body].getPosition())
        j = ph.attach_prop("ball", hand_body)
        assert isinstance(j, ode.FixedJoint) and ph.attached("ball") and not ball.free
        _run(ph, 50)
        assert [(prop, body, len(j.getFeedback()[0])) for j, prop, body in ph.attachments] == [
            ("ball", hand_body, 3)]
        b = ph.bodies[ch.geoms[-1].body]
        np.testing.assert_allclose(ball.body.getLinearVel(), b.getLinearVel(), atol=1e-3)
        ph.reset(standing_state(ch, arrays))
        assert not ph.attached("ball") and ball.free
        assert ball.pose() == (FAR, 1.0, 0.0)
        with pytest.raises(SimError, match="unknown prop"):
            ph.attach_prop("nope", hand_body)
        with pytest.raises(SimError, match="unknown body"):
            ph.attach_prop("ball", "tail")
    finally:
        ph.close()
        ph.close()


def test_prop_names_must_not_clash(humanoid):
    ch, arrays = humanoid
    with pytest.raises(SimError, match="taken"):
        Physics(ch, arrays, [PropDef(ch.body_names[1], "sphere", (0.1,), 1.0, (FAR, 1.0))])


def test_divergence_is_detected(humanoid):
    ph = _physics(humanoid, PropDef("ball", "sphere", (0.1,), 1.0, (FAR, 1.0)))
    try:
        assert ph.diverged() is None
        q, qd = ph.read_state()
        assert ph.diverged(qd) is None
        ph.prop("ball").body.setLinearVel((1e4, 0.0, 0.0))
        assert "fast" in ph.diverged(qd)
        bad = qd.copy()
        bad[4] = math.nan
        assert "non-finite" in ph.diverged(bad)
        assert issubclass(DivergenceError, SimError)
    finally:
        ph.close()


def test_poses_name_every_body_and_prop(humanoid):
    ch, _ = humanoid
    ph = _physics(humanoid, PropDef("bag", "sphere", (0.1,), 3.0, (FAR, 1.0),
                                    hanging=Hanging((FAR, 2.0), links=2)))
    try:
        names = ph.pose_names()
        assert names == [*ch.body_names, "bag", "bag.link0", "bag.link1"]
        poses = ph.poses()
        assert len(poses) == len(names)
        assert poses[len(ch.body_names)] == (FAR, 1.0, 0.0)
        assert poses[-1][:2] == pytest.approx((FAR, 1.25))  # the lower link's centre
    finally:
        ph.close()


# ---- hinges near +-180 deg (the shoulders' range ends at 180) ---------------------------------
@pytest.mark.parametrize(("degrees", "rate"), [(175.0, 3.0), (178.0, 2.0), (180.0, 0.0)])
def test_free_flight_with_arms_raised_gains_no_energy(humanoid, degrees, rate):
    """Controller off, gravity on, no ground: both arms raised to 175-180 deg (moving up into
    the 180 deg stop). Before the fix ODE read the angle past 180 as -180 + x, below the low
    stop, and the stop's correction added ~60 kJ in 2 s; now the energy never rises and the
    shoulders stay inside their range, read without a wrap."""
    ch, arrays = humanoid
    q = standing_state(ch, arrays)
    q[1] += 5.0  # far above the ground: free flight
    qd = np.zeros_like(q)
    shoulders = [3 + ch.hinge_index(n) for n in ch.hinge_names if n.startswith("shoulder")]
    assert len(shoulders) == 2
    q[shoulders] = math.radians(degrees)
    qd[shoulders] = rate
    ph = Physics(ch, arrays)
    try:
        ph.reset(q, qd)
        np.testing.assert_allclose(ph.read_state()[0], q, atol=1e-9)
        e0 = _energy(ph)
        worst = -math.inf
        for _ in range(2000):
            ph.step()
            worst = max(worst, _energy(ph) - e0)
            angles = ph.read_state()[0][shoulders]
            # (a stop is soft: 0.2 deg of overshoot at 3 rad/s; a wrap would read ~ -180)
            assert np.all(angles <= math.pi + math.radians(0.5)) and np.all(angles > 0.0)
        assert worst <= 1e-6 * e0, f"energy rose by {worst:.3f} J"
    finally:
        ph.close()


def test_only_hinges_reaching_180_move_their_ode_zero(humanoid):
    from sim.physics import hinge_zero

    ch, arrays = humanoid
    ph = Physics(ch, arrays)
    try:
        moved = {ch.hinge_names[i]: math.degrees(z) for i, z in ph.hinge_zeros}
        for k, (lo, hi) in enumerate(np.degrees(ch.limits)):
            name = ch.hinge_names[k]
            if hi >= 160.0 or lo <= -160.0:
                assert moved[name] == pytest.approx(0.5 * (lo + hi))
            else:
                assert name not in moved
        assert moved  # the humanoid's shoulders
    finally:
        ph.close()
    with pytest.raises(SimError, match="cannot be kept"):
        hinge_zero(-math.radians(175.0), math.radians(175.0))


def test_catch_weld_conserves_momentum(humanoid):
    """Gravity off, no ground contact: a 7 kg ball flying at 4 m/s reaches the right hand of
    the floating character and is welded to it the moment it is within reach. The weld is an
    internal impulse: the total linear momentum (x, y) and the angular momentum about the
    origin of character + ball are the same before and after (an inelastic collision: kinetic
    energy is lost), and the ball then moves with the hand."""
    ch, arrays = humanoid
    q = standing_state(ch, arrays)
    q[1] += 3.0
    ph = Physics(ch, arrays, [PropDef("ball", "sphere", (0.12,), 7.0, (0.0, 0.0))])
    try:
        ph.world.setGravity((0.0, 0.0, 0.0))
        ph.reset(q)
        hand = ph.geoms[ch.hands[0]]
        hx, hy, _ = hand.getPosition()
        ball = ph.prop("ball")
        ball.body.setPosition((hx + 0.5, hy, 0.0))
        ball.body.setLinearVel((-4.0, 0.0, 0.0))
        reach = 0.12 + ch.geom(ch.hands[0]).radius + 0.01
        before = after = None
        e_before = e_after = None
        for _ in range(400):
            if before is None:
                x, y, _z = ball.body.getPosition()
                hx, hy, _ = hand.getPosition()
                if math.hypot(x - hx, y - hy) <= reach:
                    before, e_before = _momentum(ph), _energy(ph)
                    ph.attach_prop("ball", ch.body_names[ch.geom(ch.hands[0]).body])
            ph.step()
            if before is not None and after is None:
                after, e_after = _momentum(ph), _energy(ph)
        assert before is not None, "the ball never reached the hand"
        print(f"momentum before {before}, after {after}; kinetic energy lost "
              f"{e_before - e_after:.2f} J")
        np.testing.assert_allclose(after[:2], before[:2], rtol=0, atol=1e-6 * 28.0)
        assert after[2] == pytest.approx(before[2], abs=1e-5 * 28.0)
        assert e_after < e_before  # inelastic
        end = _momentum(ph)
        np.testing.assert_allclose(end, before, rtol=0, atol=1e-4)
        body = ph.bodies[ch.geom(ch.hands[0]).body]
        # (the weld is as soft as every joint, CFM 1e-6: 1.3 mm/s of 2.9 m/s measured)
        np.testing.assert_allclose(ball.body.getLinearVel()[:2],
                                   body.getPointVel(ball.body.getPosition())[:2], rtol=2e-3)
    finally:
        ph.close()
