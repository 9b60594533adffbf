"""Planar kinematics and dynamics of a character (numba-compiled).

Coordinates q = [x, y, phi, theta_1..theta_n]: root CoM position and angle, then hinge angles.
For body b with mass m_b, inertia I_b, CoM p_b and angle alpha_b (phi plus the hinges on its path
from the root), the CoM Jacobian Jv_b has the identity in the x, y columns and
perp(p_b - o_j) = (-(p_b - o_j)_y, (p_b - o_j)_x) in the column of the root angle (o = root CoM)
and of every hinge j on its path (o_j the hinge's world position); Jw_b has 1 in those columns.

    M = sum m Jv^T Jv + I Jw^T Jw,  h = C + G,  C = sum m Jv^T (dJv qd),  G = -sum m Jv^T g

with g = (0, -GRAVITY). The equations of motion are M qdd + h = S^T tau + J_c^T f. There is no
gyroscopic term in the plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.character import ROOT_DOF, Character
from sim.linalg import dot, gram, matvec, solve, tmatvec

GRAVITY = 9.81  # m s^-2


@dataclass(frozen=True)
class ModelArrays:
    """The constant arrays the compiled functions need, derived from a Character."""

    parent: np.ndarray
    a_par: np.ndarray  # (nb, 2) parent CoM -> hinge anchor, parent frame, zero pose
    a_chi: np.ndarray  # (nb, 2) hinge anchor -> child CoM, child frame, zero pose
    path: np.ndarray  # (nb, nb) bool: path[b, k] is True when hinge of body k moves body b
    mass: np.ndarray
    inertia: np.ndarray
    feet: np.ndarray
    sole_local: np.ndarray  # (nf, 2) sole centre relative to the foot CoM, zero pose
    heel_local: np.ndarray  # (nf, 2)
    toe_local: np.ndarray  # (nf, 2)
    point_body: np.ndarray
    point_local: np.ndarray
    point_radius: np.ndarray

    @classmethod
    def from_character(cls, ch: Character) -> ModelArrays:
        nb = ch.n_bodies
        a_par = np.zeros((nb, 2))
        a_chi = np.zeros((nb, 2))
        path = np.zeros((nb, nb), dtype=np.bool_)
        for b in range(1, nb):
            par = ch.parent[b]
            a_par[b] = ch.anchor0[b] - ch.com0[par]
            a_chi[b] = ch.com0[b] - ch.anchor0[b]
            k = b
            while k > 0:
                path[b, k] = True
                k = ch.parent[k]
        fc = ch.com0[ch.feet]
        return cls(
            parent=ch.parent.copy(), a_par=a_par, a_chi=a_chi, path=path,
            mass=ch.mass.copy(), inertia=ch.inertia.copy(), feet=ch.feet.copy(),
            sole_local=0.5 * (ch.heel0 + ch.toe0) - fc,
            heel_local=ch.heel0 - fc, toe_local=ch.toe0 - fc,
            point_body=ch.point_body.copy(),
            point_local=ch.point0 - ch.com0[ch.point_body],
            point_radius=ch.point_radius.copy(),
        )

    def args(self) -> tuple:
        return (self.parent, self.a_par, self.a_chi, self.path, self.mass, self.inertia)


@njit(cache=True)
def _rot(a: float, v: np.ndarray) -> tuple[float, float]:
    c, s = np.cos(a), np.sin(a)
    return c * v[0] - s * v[1], s * v[0] + c * v[1]


@njit(cache=True)
def forward_kinematics(q, parent, a_par, a_chi):
    """Body angles (nb,), CoMs (nb, 2) and hinge anchors (nb, 2; the root's is its CoM)."""
    nb = parent.shape[0]
    alpha = np.empty(nb)
    p = np.empty((nb, 2))
    o = np.empty((nb, 2))
    alpha[0] = q[2]
    p[0, 0] = q[0]
    p[0, 1] = q[1]
    o[0] = p[0]
    for b in range(1, nb):
        par = parent[b]
        alpha[b] = alpha[par] + q[ROOT_DOF + b - 1]
        rx, ry = _rot(alpha[par], a_par[b])
        o[b, 0] = p[par, 0] + rx
        o[b, 1] = p[par, 1] + ry
        cx, cy = _rot(alpha[b], a_chi[b])
        p[b, 0] = o[b, 0] + cx
        p[b, 1] = o[b, 1] + cy
    return alpha, p, o


@njit(cache=True)
def body_point(alpha, p, b, local):
    """World position of a point given relative to body b's CoM in the zero pose."""
    rx, ry = _rot(alpha[b], local)
    return np.array([p[b, 0] + rx, p[b, 1] + ry])


@njit(cache=True)
def point_jacobian(r, b, o, path, n):
    """(2, n) Jacobian of the world point r fixed on body b."""
    J = np.zeros((2, n))
    J[0, 0] = 1.0
    J[1, 1] = 1.0
    J[0, 2] = -(r[1] - o[0, 1])
    J[1, 2] = r[0] - o[0, 0]
    nb = path.shape[0]
    for k in range(1, nb):
        if path[b, k]:
            J[0, ROOT_DOF + k - 1] = -(r[1] - o[k, 1])
            J[1, ROOT_DOF + k - 1] = r[0] - o[k, 0]
    return J


@njit(cache=True)
def velocity_accelerations(qd, parent, p, o):
    """Body angular velocities omega (nb,) and the velocity-product (centripetal) accelerations
    of the body CoMs at qdd = 0, acc (nb, 2): the part of every point's acceleration that does
    not depend on qdd."""
    nb = parent.shape[0]
    omega = np.empty(nb)
    acc = np.zeros((nb, 2))
    omega[0] = qd[2]
    for b in range(1, nb):
        par = parent[b]
        omega[b] = omega[par] + qd[ROOT_DOF + b - 1]
        w2p = omega[par] * omega[par]
        w2 = omega[b] * omega[b]
        aox = acc[par, 0] - w2p * (o[b, 0] - p[par, 0])
        aoy = acc[par, 1] - w2p * (o[b, 1] - p[par, 1])
        acc[b, 0] = aox - w2 * (p[b, 0] - o[b, 0])
        acc[b, 1] = aoy - w2 * (p[b, 1] - o[b, 1])
    return omega, acc


@njit(cache=True)
def momentum_bias(q, qd, parent, a_par, a_chi, mass, feet, sole_local):
    """The velocity-product terms that `A_L qdd`, `A_H qdd` and `J_s qdd` leave out:

        Ldot = A_L qdd + b_L,   Hdot (about the CoM) = A_H qdd + b_H,
        a foot stays planted when J_s qdd + b_S = 0.

    Returns (b_L (2,), b_H, b_S (3 nf,)); b_S holds the sole centres' accelerations at
    qdd = 0 and 0 in the foot-angle rows (no velocity-product term in the plane).
    b_H = sum_b (p_b - c) x m_b acc_b: at qdd = 0 no body has an angular acceleration, and the
    d/dt of (p_b - c) applied to m_b v_b sums to zero over the bodies.
    """
    alpha, p, o = forward_kinematics(q, parent, a_par, a_chi)
    omega, acc = velocity_accelerations(qd, parent, p, o)
    nb = parent.shape[0]
    mtot = 0.0
    c = np.zeros(2)
    bL = np.zeros(2)
    for b in range(nb):
        mtot += mass[b]
        c += mass[b] * p[b]
        bL += mass[b] * acc[b]
    c /= mtot
    bH = 0.0
    for b in range(nb):
        bH += mass[b] * ((p[b, 0] - c[0]) * acc[b, 1] - (p[b, 1] - c[1]) * acc[b, 0])
    nf = feet.shape[0]
    bS = np.zeros(3 * nf)
    for f in range(nf):
        b = feet[f]
        s = body_point(alpha, p, b, sole_local[f])
        w2 = omega[b] * omega[b]
        bS[3 * f] = acc[b, 0] - w2 * (s[0] - p[b, 0])
        bS[3 * f + 1] = acc[b, 1] - w2 * (s[1] - p[b, 1])
    return bL, bH, bS


@njit(cache=True)
def _mass_terms_into(q, qd, parent, a_par, a_chi, path, mass, inertia, M, h, c, cd, A_L, A_H):
    """`dynamics`' terms written into the given arrays (M (n, n), h (n,), c (2,), cd (2,),
    A_L (2, n), A_H (n,)); returns the kinematics (alpha, p, o, omega). See `dynamics` for
    why only each body's own columns are summed."""
    nb = parent.shape[0]
    n = q.shape[0]
    alpha, p, o = forward_kinematics(q, parent, a_par, a_chi)
    omega, acc = velocity_accelerations(qd, parent, p, o)
    M[:, :] = 0.0
    h[:] = 0.0
    A_L[:, :] = 0.0
    A_H[:] = 0.0  # holds the angular momentum rows about the root CoM until the end
    mtot = 0.0
    c[0] = 0.0
    c[1] = 0.0
    cols = np.empty(n, dtype=np.int64)
    jv0 = np.empty(n)
    jv1 = np.empty(n)
    jw = np.empty(n)
    for b in range(nb):
        m = mass[b]
        ib = inertia[b]
        px, py = p[b, 0], p[b, 1]
        cols[0], jv0[0], jv1[0], jw[0] = 0, 1.0, 0.0, 0.0
        cols[1], jv0[1], jv1[1], jw[1] = 1, 0.0, 1.0, 0.0
        cols[2], jv0[2], jv1[2], jw[2] = 2, -(py - o[0, 1]), px - o[0, 0], 1.0
        nc = 3
        for k in range(1, nb):
            if path[b, k]:
                cols[nc] = ROOT_DOF + k - 1
                jv0[nc] = -(py - o[k, 1])
                jv1[nc] = px - o[k, 0]
                jw[nc] = 1.0
                nc += 1
        ay = acc[b, 1] + GRAVITY
        ax = acc[b, 0]
        dpx = px - p[0, 0]
        dpy = py - p[0, 1]
        for a in range(nc):
            i = cols[a]
            for e in range(nc):
                j = cols[e]
                M[i, j] += m * (jv0[a] * jv0[e] + jv1[a] * jv1[e]) + ib * jw[a] * jw[e]
            h[i] += m * (jv0[a] * ax + jv1[a] * ay)
            A_L[0, i] += m * jv0[a]
            A_L[1, i] += m * jv1[a]
            A_H[i] += m * (dpx * jv1[a] - dpy * jv0[a])
            A_H[i] += ib * jw[a]
        mtot += m
        c[0] += m * px
        c[1] += m * py
    c[0] /= mtot
    c[1] /= mtot
    dx = c[0] - p[0, 0]
    dy = c[1] - p[0, 1]
    for i in range(n):
        A_H[i] = A_H[i] - (dx * A_L[1, i] - dy * A_L[0, i])
    cd[0] = dot(A_L[0], qd) / mtot
    cd[1] = dot(A_L[1], qd) / mtot
    return alpha, p, o, omega


@njit(cache=True)
def dynamics(q, qd, parent, a_par, a_chi, path, mass, inertia):
    """Mass matrix M (n, n), bias h = C + G (n,), CoM c, its velocity, momentum rows.

    Returns (M, h, alpha, p, o, omega, c, cd, A_L, A_H): A_L (2, n) maps qd to linear momentum,
    A_H (n,) maps qd to the angular momentum about the CoM.

    Body b's Jacobians are non-zero only in its own columns (x, y, root angle and the hinges
    on its path), so only those entries are summed: a skipped term is exactly +-0 and adding
    it changes no sum (the sums start at +0 and keep the body order), so M, h and the
    momentum rows are the same bits as the dense sums over all n x n entries.
    """
    n = q.shape[0]
    M = np.empty((n, n))
    h = np.empty(n)
    c = np.empty(2)
    cd = np.empty(2)
    A_L = np.empty((2, n))
    A_H = np.empty(n)
    alpha, p, o, omega = _mass_terms_into(q, qd, parent, a_par, a_chi, path, mass, inertia,
                                          M, h, c, cd, A_L, A_H)
    return M, h, alpha, p, o, omega, c, cd, A_L, A_H


@njit(cache=True)
def feet_terms(alpha, p, o, path, feet, sole_local, heel_local, toe_local, n):
    """Support Jacobian J_s (3 nf, n): per foot the sole-centre velocity rows and the angle row;
    and the world heel, toe and sole-centre points (nf, 2) each."""
    nf = feet.shape[0]
    Js = np.zeros((3 * nf, n))
    heel = np.empty((nf, 2))
    toe = np.empty((nf, 2))
    sole = np.empty((nf, 2))
    nb = path.shape[0]
    for f in range(nf):
        b = feet[f]
        s = body_point(alpha, p, b, sole_local[f])
        sole[f] = s
        heel[f] = body_point(alpha, p, b, heel_local[f])
        toe[f] = body_point(alpha, p, b, toe_local[f])
        J = point_jacobian(s, b, o, path, n)
        Js[3 * f] = J[0]
        Js[3 * f + 1] = J[1]
        Js[3 * f + 2, 2] = 1.0
        for k in range(1, nb):
            if path[b, k]:
                Js[3 * f + 2, ROOT_DOF + k - 1] = 1.0
    return Js, heel, toe, sole


@njit(cache=True)
def lowest_clearance(alpha, p, point_body, point_local, point_radius):
    """Smallest height above the ground of the outline points minus their radii, and its index."""
    best = 1e9
    arg = -1
    for i in range(point_body.shape[0]):
        b = point_body[i]
        _rx, ry = _rot(alpha[b], point_local[i])
        h = (p[b, 1] + ry) - point_radius[i]  # body_point's y, without its array
        if h < best:
            best = h
            arg = i
    return best, arg


@njit(cache=True)
def inverse_dynamics(M, h, Js, qdd):
    """Floating-base inverse dynamics with the root unactuated (paper eq. 8-10).

    Root rows: M_r qdd + h_r = J_sr^T f  ->  f = J_sr (J_sr^T J_sr)^-1 (M_r qdd + h_r), the
    least-norm support wrench (per foot: fx, fy, torque about the sole centre).
    Hinge rows: tau = M_x qdd + h_x - J_sx^T f. Returns (tau, f).
    """
    n = M.shape[0]
    r = matvec(M[:ROOT_DOF], qdd) + h[:ROOT_DOF]
    Jsr = Js[:, :ROOT_DOF]
    f = matvec(Jsr, solve(gram(Jsr), r))
    tau = matvec(M[ROOT_DOF:], qdd) + h[ROOT_DOF:] - tmatvec(Js[:, ROOT_DOF:n], f)
    return tau, f


@njit(cache=True)
def step_model(q, qd, parent, a_par, a_chi, path, mass, inertia, feet, sole_local, heel_local,
               toe_local, point_body, point_local, point_radius):
    """Everything the controller needs for one step, in one compiled call.

    Returns (M, h, c, cd, A_L, A_H, Js, contact_points (2 nf, 2: heel, toe per foot),
    sole_x (nf,), support back edge x, support front edge x, lowest outline clearance).
    """
    n = q.shape[0]
    M, h, alpha, p, o, omega, c, cd, A_L, A_H = dynamics(q, qd, parent, a_par, a_chi, path,
                                                        mass, inertia)
    Js, heel, toe, sole = feet_terms(alpha, p, o, path, feet, sole_local, heel_local, toe_local, n)
    nf = feet.shape[0]
    pts = np.empty((2 * nf, 2))
    lo = 1e9
    hi = -1e9
    for f in range(nf):
        pts[2 * f] = heel[f]
        pts[2 * f + 1] = toe[f]
        lo = min(lo, heel[f, 0])
        hi = max(hi, toe[f, 0])
    clearance, _ = lowest_clearance(alpha, p, point_body, point_local, point_radius)
    return M, h, c, cd, A_L, A_H, Js, pts, sole[:, 0].copy(), lo, hi, clearance


@njit(cache=True)
def _model_into(q, qd, parent, a_par, a_chi, path, mass, inertia, feet, sole_local, heel_local,
                toe_local, point_body, point_local, point_radius, M, h, c, cd, A_L, A_H, Js,
                pts, sole_x):
    """`step_model` computed straight into the given arrays (shaped as it returns them):
    `dynamics` and `feet_terms` with the same operations in the same order, without their
    arrays for the results, the per-point arrays of `body_point` and `point_jacobian`, and the
    copies into the outputs. Returns (support back edge x, front edge x, lowest clearance)."""
    alpha, p, o, omega = _mass_terms_into(q, qd, parent, a_par, a_chi, path, mass, inertia,
                                          M, h, c, cd, A_L, A_H)
    nb = parent.shape[0]
    # feet_terms and step_model's support and points
    nf = feet.shape[0]
    Js[:, :] = 0.0
    lo = 1e9
    hi = -1e9
    for f in range(nf):
        b = feet[f]
        rx, ry = _rot(alpha[b], sole_local[f])
        sx, sy = p[b, 0] + rx, p[b, 1] + ry
        sole_x[f] = sx
        rx, ry = _rot(alpha[b], heel_local[f])
        pts[2 * f, 0], pts[2 * f, 1] = p[b, 0] + rx, p[b, 1] + ry
        rx, ry = _rot(alpha[b], toe_local[f])
        pts[2 * f + 1, 0], pts[2 * f + 1, 1] = p[b, 0] + rx, p[b, 1] + ry
        Js[3 * f, 0] = 1.0
        Js[3 * f + 1, 1] = 1.0
        Js[3 * f, 2] = -(sy - o[0, 1])
        Js[3 * f + 1, 2] = sx - o[0, 0]
        Js[3 * f + 2, 2] = 1.0
        for k in range(1, nb):
            if path[b, k]:
                Js[3 * f, ROOT_DOF + k - 1] = -(sy - o[k, 1])
                Js[3 * f + 1, ROOT_DOF + k - 1] = sx - o[k, 0]
                Js[3 * f + 2, ROOT_DOF + k - 1] = 1.0
        lo = min(lo, pts[2 * f, 0])
        hi = max(hi, pts[2 * f + 1, 0])
    clearance, _ = lowest_clearance(alpha, p, point_body, point_local, point_radius)
    return lo, hi, clearance


class PackedModel:
    """A character's constant model arrays in three (floats, ints, the path matrix) and one
    flat output buffer with the step's model terms as views into it, for `step_model_packed`.

    A compiled call pays for the type check and unboxing of every argument (~0.1 us per array
    here): `step_model`'s inputs and outputs are 24 arrays, `step_model_packed` takes 6. The
    views `M, h, c, cd, A_L, A_H, Js, pts, sole_x` (shaped as `step_model` returns them) are
    overwritten at each call."""

    def __init__(self, a: ModelArrays, n: int):
        nb, nf, npt = len(a.parent), len(a.feet), len(a.point_body)
        self.floats = np.concatenate([
            a.a_par.ravel(), a.a_chi.ravel(), a.mass, a.inertia, a.sole_local.ravel(),
            a.heel_local.ravel(), a.toe_local.ravel(), a.point_local.ravel(),
            a.point_radius]).astype(np.float64)
        self.ints = np.concatenate([[nb, nf, npt], a.parent, a.feet,
                                    a.point_body]).astype(np.int64)
        self.path = np.ascontiguousarray(a.path)
        shapes = ((n, n), (n,), (2,), (2,), (2, n), (n,), (3 * nf, n), (2 * nf, 2), (nf,))
        self.out = np.empty(sum(int(np.prod(s)) for s in shapes))
        views, at = [], 0
        for s in shapes:
            size = int(np.prod(s))
            views.append(self.out[at:at + size].reshape(s))
            at += size
        (self.M, self.h, self.c, self.cd, self.A_L, self.A_H, self.Js, self.pts,
         self.sole_x) = views

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(M, h, c, cd, A_L, A_H, Js, pts, sole_x): the views written by each call."""
        return (self.M, self.h, self.c, self.cd, self.A_L, self.A_H, self.Js, self.pts,
                self.sole_x)

    def args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arguments of `step_model_packed` after q and qd."""
        return self.floats, self.ints, self.path, self.out


@njit(cache=True)
def step_model_packed(q, qd, floats, ints, path, out):
    """`step_model` with the constants and outputs packed as `PackedModel` holds them: the
    same operations on the same values (the unpacked arrays are views of the packed ones),
    computed straight into `out` (`_model_into`, no new arrays for Python) and returning
    (support back edge x, front edge x, lowest outline clearance)."""
    nb, nf, npt = ints[0], ints[1], ints[2]
    parent = ints[3:3 + nb]
    feet = ints[3 + nb:3 + nb + nf]
    point_body = ints[3 + nb + nf:3 + nb + nf + npt]
    at = 0
    a_par = floats[at:at + 2 * nb].reshape((nb, 2))
    at += 2 * nb
    a_chi = floats[at:at + 2 * nb].reshape((nb, 2))
    at += 2 * nb
    mass = floats[at:at + nb]
    at += nb
    inertia = floats[at:at + nb]
    at += nb
    sole_local = floats[at:at + 2 * nf].reshape((nf, 2))
    at += 2 * nf
    heel_local = floats[at:at + 2 * nf].reshape((nf, 2))
    at += 2 * nf
    toe_local = floats[at:at + 2 * nf].reshape((nf, 2))
    at += 2 * nf
    point_local = floats[at:at + 2 * npt].reshape((npt, 2))
    at += 2 * npt
    point_radius = floats[at:at + npt]
    n = q.shape[0]
    M = out[0:n * n].reshape((n, n))
    at = n * n
    h = out[at:at + n]
    at += n
    c = out[at:at + 2]
    at += 2
    cd = out[at:at + 2]
    at += 2
    A_L = out[at:at + 2 * n].reshape((2, n))
    at += 2 * n
    A_H = out[at:at + n]
    at += n
    Js = out[at:at + 3 * nf * n].reshape((3 * nf, n))
    at += 3 * nf * n
    pts = out[at:at + 4 * nf].reshape((2 * nf, 2))
    at += 4 * nf
    sole_x = out[at:at + nf]
    return _model_into(q, qd, parent, a_par, a_chi, path, mass, inertia, feet, sole_local,
                       heel_local, toe_local, point_body, point_local, point_radius, M, h, c, cd,
                       A_L, A_H, Js, pts, sole_x)


#: Codes of `checked_inverse_dynamics`.
WRENCH_OK, WRENCH_NO_NORMAL_FORCE, WRENCH_FRICTION_CONE, WRENCH_COP_OUTSIDE = 0, 1, 2, 3
WRENCH_REASONS = ("", "no_normal_force", "friction_cone", "cop_outside_support")


def inverse_dynamics_feet(M: np.ndarray, h: np.ndarray, Js: np.ndarray, qdd: np.ndarray,
                          points: np.ndarray, sole_x: np.ndarray, margin: float
                          ) -> tuple[np.ndarray, np.ndarray, float]:
    """Inverse dynamics for stance feet apart (after a step), the support wrench shared between
    them physically instead of by least norm.

    The root rows fix the total ground force (F_x, F_y) and its moment, hence the total CoP p
    (`points`: heel, toe per stance foot; the soles on the ground). With p between the rear
    and the front foot's sole centres the force is split between the feet by the lever rule,
    each foot's CoP at its sole centre (both feet loaded, neither tipping); with p beyond one
    sole centre that foot carries it all, its CoP at p (kept `margin` m inside its heel and
    toe). The least-norm wrench of `inverse_dynamics`
    would instead make the moment from foot torques (a couple costs less, in N m, than shifting
    weight between feet 0.3 m apart), i.e. each foot's own CoP beyond its toe or heel, and
    the feet tip. Returns (tau, f, p) with f per foot (fx, fy, torque about its sole centre)."""
    n = M.shape[0]
    r = matvec(M[:ROOT_DOF], qdd) + h[:ROOT_DOF]
    nf = len(sole_x)
    heel = points[0::2, 0]
    toe = points[1::2, 0]
    ys = 0.5 * (points[0::2, 1] + points[1::2, 1])
    # Root rows per foot: fx, fy, and (s_x - o_x) fy - (s_y - o_y) fx + torque = r[2]; o_x, o_y
    # follow from any foot's rows of Js (its sole-centre point Jacobian's root-angle column).
    ox = sole_x[0] - Js[1, 2]
    oy = ys[0] + Js[0, 2]
    fx_tot, fy_tot = float(r[0]), float(r[1])
    f = np.zeros(3 * nf)
    if fy_tot <= 0.0:
        p = math.nan
        shares = np.full(nf, 1.0 / nf)
        cops = sole_x.copy()
    else:
        moment_o = float(r[2]) + ox * fy_tot - oy * fx_tot  # about the world origin
        p = (moment_o + dot(ys, np.full(nf, fx_tot / nf))) / fy_tot
        shares = np.zeros(nf)
        order = np.argsort(sole_x)
        rear, front = int(order[0]), int(order[-1])
        cops = sole_x.copy()
        if sole_x[rear] <= p <= sole_x[front] and sole_x[front] - sole_x[rear] > 1e-9:
            a = (sole_x[front] - p) / (sole_x[front] - sole_x[rear])
            shares[rear], shares[front] = a, 1.0 - a
        else:
            k = rear if p < sole_x[rear] else front
            shares[k] = 1.0
            cops[k] = min(max(p, heel[k] + margin), toe[k] - margin)
    for k in range(nf):
        fyk = shares[k] * fy_tot
        fxk = shares[k] * fx_tot
        f[3 * k] = fxk
        f[3 * k + 1] = fyk
        f[3 * k + 2] = (cops[k] - sole_x[k]) * fyk
    # The moment the shares leave over (p clamped, or the fx lever arms) goes to the feet's
    # torques equally, so that the root rows hold exactly.
    resid = float(r[2]) - sum(
        (sole_x[k] - ox) * f[3 * k + 1] - (ys[k] - oy) * f[3 * k] + f[3 * k + 2] for k in range(nf))
    for k in range(nf):
        f[3 * k + 2] += resid / nf
    tau = matvec(M[ROOT_DOF:], qdd) + h[ROOT_DOF:] - tmatvec(Js[:, ROOT_DOF:n], f)
    return tau, f, p


@njit(cache=True)
def checked_inverse_dynamics(M, h, Js, qdd, sole_x, lo, hi, mu):
    """`inverse_dynamics` with the support wrench checked:
    positive total normal force, total tangential force inside the friction cone (mu), implied
    CoP inside [lo, hi]. Returns (tau, code, cop)."""
    tau, f = inverse_dynamics(M, h, Js, qdd)
    nf = sole_x.shape[0]
    fx = 0.0
    fy = 0.0
    mom = 0.0
    for k in range(nf):
        fx += f[3 * k]
        fy += f[3 * k + 1]
        mom += sole_x[k] * f[3 * k + 1] + f[3 * k + 2]
    if fy <= 0.0:
        return tau, WRENCH_NO_NORMAL_FORCE, np.nan
    cop = mom / fy
    if abs(fx) > mu * fy:
        return tau, WRENCH_FRICTION_CONE, cop
    if cop < lo or cop > hi:
        return tau, WRENCH_COP_OUTSIDE, cop
    return tau, WRENCH_OK, cop


@njit(cache=True)
def checked_inverse_dynamics_lift(M, h, Js, qdd, sole_x, points, lo, hi, mu):
    """`checked_inverse_dynamics` and the highest of the `points`' heights (their y), in one
    compiled call: (tau, code, cop, highest y). The height is Python's `max` over the y
    values in order (a later value replaces the kept one only if it is greater), so a NaN
    behaves as it does under `max(points[:, 1].tolist())`."""
    tau, code, cop = checked_inverse_dynamics(M, h, Js, qdd, sole_x, lo, hi, mu)
    top = points[0, 1]
    for i in range(1, points.shape[0]):
        if points[i, 1] > top:
            top = points[i, 1]
    return tau, code, cop, top


@njit(cache=True)
def step_model_held(q, qd, floats, ints, path, out, qdd, mu, neg_limit, limit, tau):
    """`step_model_packed`, then `checked_inverse_dynamics_lift` of the held accelerations
    `qdd` on the model terms it wrote (every foot in stance), then the torques clamped to
    [neg_limit, limit] as `Physics.apply_torques` clamps them, written into `tau`: one
    compiled call for a step between QP solves. Returns (support back edge x, front edge x,
    lowest outline clearance, wrench code, wrench CoP, highest heel or toe y)."""
    lo, hi, clearance = step_model_packed(q, qd, floats, ints, path, out)
    n = q.shape[0]
    nf = ints[1]
    # The views PackedModel.arrays() gives, in its order: M, h, c, cd, A_L, A_H, Js, pts,
    # sole_x.
    M = out[0:n * n].reshape((n, n))
    at = n * n
    h = out[at:at + n]
    at += n + 4 + 2 * n + n  # h, c, cd, A_L, A_H
    Js = out[at:at + 3 * nf * n].reshape((3 * nf, n))
    at += 3 * nf * n
    pts = out[at:at + 4 * nf].reshape((2 * nf, 2))
    at += 4 * nf
    sole_x = out[at:at + nf]
    t, code, cop, top = checked_inverse_dynamics_lift(M, h, Js, qdd, sole_x, pts, lo, hi, mu)
    for i in range(t.shape[0]):
        # np.minimum(np.maximum(t, neg_limit), limit) element by element: numpy keeps the
        # first operand when it compares >= (<=) or is NaN, which gives the same bits.
        v = t[i]
        if not (v >= neg_limit[i] or math.isnan(v)):
            v = neg_limit[i]
        if not (v <= limit[i] or math.isnan(v)):
            v = limit[i]
        tau[i] = v
    return lo, hi, clearance, code, cop, top


def checked_inverse_dynamics_feet(M: np.ndarray, h: np.ndarray, Js: np.ndarray,
                                  qdd: np.ndarray, points: np.ndarray, sole_x: np.ndarray,
                                  lo: float, hi: float, mu: float, margin: float
                                  ) -> tuple[np.ndarray, int, float]:
    """`inverse_dynamics_feet` with the checks of `checked_inverse_dynamics`."""
    tau, f, p = inverse_dynamics_feet(M, h, Js, qdd, points, sole_x, margin)
    fy = float(f[1::3].sum())
    fx = float(f[0::3].sum())
    if fy <= 0.0:
        return tau, WRENCH_NO_NORMAL_FORCE, math.nan
    if abs(fx) > mu * fy:
        return tau, WRENCH_FRICTION_CONE, p
    if p < lo or p > hi:
        return tau, WRENCH_COP_OUTSIDE, p
    return tau, WRENCH_OK, p
