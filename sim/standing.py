"""The standing pose: the state a clip starts from (feet flat, optionally leaning so the CM is over
the support centre). Its own module so that both the rollout and the tasks (a pull's grip point
is found in it) can import it without importing each other."""

from __future__ import annotations

import math

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.dynamics import ModelArrays, forward_kinematics


def standing_state(ch: Character, arrays: ModelArrays,
                   pose: dict[int, float] | None = None) -> np.ndarray:
    """q of the standing pose: feet flat with the right heel where the zero pose has it; with
    `balance_standing`, the body leans at the ankles so the CM is over the support centre.
    `pose` ({hinge index: rad} relative to the standing pose, e.g. arms held out) changes the
    pose before the lean is found."""
    hinge = ch.standing_offsets.copy()
    for j, off in (pose or {}).items():
        hinge[j] += off
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
