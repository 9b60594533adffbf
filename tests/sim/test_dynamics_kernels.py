"""The sparse model kernels (issue 15) give the bits of the dense sums they replaced."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from sim import load_spec
from sim.character import ROOT_DOF
from sim.dynamics import (
    GRAVITY,
    PackedModel,
    checked_inverse_dynamics,
    checked_inverse_dynamics_lift,
    dynamics,
    forward_kinematics,
    point_jacobian,
    step_model,
    step_model_packed,
    velocity_accelerations,
)
from sim.linalg import matvec
from sim.rollout import Rollout


@njit(cache=False)
def dense_dynamics(q, qd, parent, a_par, a_chi, path, mass, inertia):
    """The dense n x n sums of `sim.dynamics.dynamics` before issue 15 (reference)."""
    nb = parent.shape[0]
    n = q.shape[0]
    alpha, p, o = forward_kinematics(q, parent, a_par, a_chi)
    omega, acc = velocity_accelerations(qd, parent, p, o)
    M = np.zeros((n, n))
    h = np.zeros(n)
    A_L = np.zeros((2, n))
    A_root = np.zeros(n)
    mtot = 0.0
    c = np.zeros(2)
    for b in range(nb):
        m = mass[b]
        Jv = point_jacobian(p[b], b, o, path, n)
        Jw = np.zeros(n)
        Jw[2] = 1.0
        for k in range(1, nb):
            if path[b, k]:
                Jw[ROOT_DOF + k - 1] = 1.0
        for i in range(n):
            for j in range(n):
                M[i, j] += (m * (Jv[0, i] * Jv[0, j] + Jv[1, i] * Jv[1, j])
                            + inertia[b] * Jw[i] * Jw[j])
            h[i] += m * (Jv[0, i] * acc[b, 0] + Jv[1, i] * (acc[b, 1] + GRAVITY))
            A_L[0, i] += m * Jv[0, i]
            A_L[1, i] += m * Jv[1, i]
            A_root[i] += m * ((p[b, 0] - p[0, 0]) * Jv[1, i] - (p[b, 1] - p[0, 1]) * Jv[0, i])
            A_root[i] += inertia[b] * Jw[i]
        mtot += m
        c[0] += m * p[b, 0]
        c[1] += m * p[b, 1]
    c /= mtot
    dx = c[0] - p[0, 0]
    dy = c[1] - p[0, 1]
    A_H = np.empty(n)
    for i in range(n):
        A_H[i] = A_root[i] - (dx * A_L[1, i] - dy * A_L[0, i])
    cd = matvec(A_L, qd) / mtot  # the ordered product of sim.linalg, as dynamics has it
    return M, h, alpha, p, o, omega, c, cd, A_L, A_H


def test_sparse_dynamics_is_bit_identical_to_the_dense_sums() -> None:
    """(`step_model_packed` against `step_model`: the test below.)"""
    sim = Rollout(load_spec("examples/quiet_stance.yaml"))
    a = sim.arrays
    n = len(sim.q0)
    rng = np.random.default_rng(15)
    for _ in range(300):
        q = sim.q0 + rng.normal(0.0, 0.5, n)
        qd = rng.normal(0.0, 3.0, n)
        for x, y in zip(dynamics(q, qd, *a.args()), dense_dynamics(q, qd, *a.args()),
                        strict=True):
            assert np.asarray(x).tobytes() == np.asarray(y).tobytes()
    sim.close()


@pytest.mark.parametrize("character", ["humanoid", "sumo", "lion"])
def test_packed_step_model_and_fused_inverse_dynamics_are_bit_identical(character) -> None:
    """`step_model_packed` (constants and outputs packed, 6 arguments) gives the bytes of
    `step_model`, and `checked_inverse_dynamics_lift` those of `checked_inverse_dynamics` plus
    Python's `max` of the points' heights, over random states of every character file."""
    from sim.spec import parse_spec

    spec = parse_spec({"name": "k", "character": {"model": character},
                       "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": 0.01, "decay": 0.0}})
    sim = Rollout(spec)
    a = sim.arrays
    margs = a.args() + (a.feet, a.sole_local, a.heel_local, a.toe_local, a.point_body,
                        a.point_local, a.point_radius)
    n = len(sim.q0)
    pack = PackedModel(a, n)
    rng = np.random.default_rng(151)
    for i in range(300):
        q = sim.q0 + rng.normal(0.0, 0.5, n)
        qd = rng.normal(0.0, 3.0, n)
        ref = step_model(q, qd, *margs)
        tail = step_model_packed(q, qd, *pack.args())
        for x, y in zip(pack.arrays() + tuple(tail), ref, strict=True):
            assert np.asarray(x).tobytes() == np.asarray(y).tobytes()
        M, h, _c, _cd, _al, _ah, Js, pts, sole_x, lo, hi, _cl = ref
        qdd = rng.normal(0.0, 5.0, n)
        if i % 50 == 0:  # NaN heights: max() keeps the first value unless a later one is >
            pts = pts.copy()
            pts[i // 50 % len(pts), 1] = np.nan
        tau, code, cop = checked_inverse_dynamics(M, h, Js, qdd, sole_x, lo, hi, 1.0)
        tau2, code2, cop2, top = checked_inverse_dynamics_lift(M, h, Js, qdd, sole_x, pts, lo,
                                                               hi, 1.0)
        assert tau.tobytes() == tau2.tobytes() and code == code2
        assert np.float64(cop).tobytes() == np.float64(cop2).tobytes()
        assert np.float64(top).tobytes() == np.float64(max(pts[:, 1].tolist())).tobytes()
    sim.close()


@pytest.mark.parametrize("character", ["humanoid", "lion"])
def test_held_step_kernel_gives_the_bits_of_the_separate_calls(character) -> None:
    """`step_model_held` (model terms, inverse dynamics of the held qdd, torque clamp in one
    call) writes the bytes of `step_model_packed` and returns those of
    `checked_inverse_dynamics_lift`, and its torques are the bytes of `apply_torques`'s
    clamp (np.minimum(np.maximum(tau, -limit), limit)), clamped torques included. (A NaN
    cannot reach the clamp: the inverse dynamics' solve refuses non-finite input.)"""
    from sim.dynamics import step_model_held
    from sim.spec import parse_spec

    spec = parse_spec({"name": "k", "character": {"model": character},
                       "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": 0.01, "decay": 0.0}})
    sim = Rollout(spec)
    n = len(sim.q0)
    ref_pack, pack = PackedModel(sim.arrays, n), PackedModel(sim.arrays, n)
    neg, lim = sim.physics.torque_bounds
    tau = np.empty(len(lim))
    rng = np.random.default_rng(152)
    clamped = 0
    for i in range(300):
        q = sim.q0 + rng.normal(0.0, 0.5, n)
        qd = rng.normal(0.0, 3.0, n)
        qdd = rng.normal(0.0, 5.0 if i % 3 else 500.0, n)  # large: torques past the limits
        lo, hi, cl = step_model_packed(q, qd, *ref_pack.args())
        M, h, _c, _cd, _al, _ah, Js, pts, sole_x = ref_pack.arrays()
        t_ref, code_ref, cop_ref, top_ref = checked_inverse_dynamics_lift(
            M, h, Js, qdd, sole_x, pts, lo, hi, 1.0)
        out = step_model_held(q, qd, *pack.args(), qdd, 1.0, neg, lim, tau)
        assert pack.out.tobytes() == ref_pack.out.tobytes()
        assert np.array(out[:3] + out[4:]).tobytes() == np.array(
            (lo, hi, cl, cop_ref, top_ref)).tobytes()
        assert out[3] == code_ref
        clip = np.minimum(np.maximum(t_ref, neg), lim)
        assert tau.tobytes() == clip.tobytes()
        clamped += int((clip != t_ref).sum())
    assert clamped > 0
    sim.close()
