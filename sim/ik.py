"""Inverse kinematics of a planar character: iterated pseudo-inverse (the stepping paper's
figure 6) on a chosen set of coordinates, for point, segment-angle and centre-of-mass targets.

Each iteration builds the targets' Jacobian J (rows: a body point's x and y, a body's world
angle, the CM's x and/or y; columns: the coordinates allowed to move), and updates
q += J^T (J J^T + damping I)^-1 (r_dest - r) until |r_dest - r| < tol. The tiny damping keeps
the update defined at a straight knee (a row of J vanishing); hinge angles are kept within their
limits. The legs are found from the character's data: a foot's chain is the hinges between the
root and the foot (`leg_hinges`), nothing names a joint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.character import ROOT_DOF, Character
from sim.dynamics import ModelArrays, body_point, forward_kinematics, point_jacobian
from sim.linalg import matmul, solve, tmatvec

IK_TOLERANCE = 1e-4  # m (or rad): a target is reached within this
IK_MAX_ITERATIONS = 50
IK_DAMPING = 1e-8


def leg_hinges(character: Character, foot_body: int) -> list[int]:
    """Hinge indices from the root down to the foot `foot_body` (its own hinge last)."""
    chain = []
    b = int(foot_body)
    while b > 0:
        chain.append(b - 1)
        b = int(character.parent[b])
    return chain[::-1]


@dataclass(frozen=True)
class Target:
    """One IK target. kind "point": body point `local` (relative to the body's CoM in the zero
    pose) at `value` (x, y); "angle": the body's world angle at value[0] (rad); "cm": the CM's
    x at value[0] (and its y at value[1] when `both` is True)."""

    kind: str
    value: tuple[float, ...]
    body: int = 0
    local: tuple[float, float] = (0.0, 0.0)
    both: bool = False


@njit(cache=True)
def _cm_terms(p, o, path, mass, mtot, n):
    """(2, n) Jacobian of the CM and the CM (2,): each body's mass-weighted term added in body
    order, then divided by the total mass `mtot` (one compiled loop: the IK's costliest rows)."""
    Jc = np.zeros((2, n))
    c = np.zeros(2)
    for b in range(mass.shape[0]):
        J = point_jacobian(p[b], b, o, path, n)
        m = mass[b]
        for i in range(2):
            for j in range(n):
                Jc[i, j] += m * J[i, j]
            c[i] += m * p[b, i]
    for i in range(2):
        for j in range(n):
            Jc[i, j] /= mtot
        c[i] /= mtot
    return Jc, c


def _rows(q: np.ndarray, a: ModelArrays, targets: list[Target]) -> tuple[np.ndarray, np.ndarray]:
    """(residual r_dest - r, Jacobian rows over every coordinate) of the targets at q."""
    n = q.shape[0]
    alpha, p, o = forward_kinematics(q, a.parent, a.a_par, a.a_chi)
    res: list[float] = []
    rows: list[np.ndarray] = []
    mtot = float(a.mass.sum())
    for tg in targets:
        if tg.kind == "point":
            r = body_point(alpha, p, tg.body, np.array(tg.local))
            J = point_jacobian(r, tg.body, o, a.path, n)
            res += [tg.value[0] - r[0], tg.value[1] - r[1]]
            rows += [J[0], J[1]]
        elif tg.kind == "angle":
            row = np.zeros(n)
            row[2] = 1.0
            row[ROOT_DOF:] = a.path[tg.body, 1:]
            res.append(tg.value[0] - alpha[tg.body])
            rows.append(row)
        elif tg.kind == "cm":
            Jc, c = _cm_terms(p, o, a.path, a.mass, mtot, n)
            res.append(tg.value[0] - c[0])
            rows.append(Jc[0])
            if tg.both:
                res.append(tg.value[1] - c[1])
                rows.append(Jc[1])
        else:
            raise ValueError(f"unknown IK target kind {tg.kind!r}")
    return np.array(res), np.array(rows)


@dataclass(frozen=True)
class IkResult:
    q: np.ndarray
    residual: float  # largest |r_dest - r| at the end (m or rad)
    iterations: int


def solve_ik(q0: np.ndarray, arrays: ModelArrays, limits: np.ndarray, targets: list[Target],
             dofs: list[int], tol: float = IK_TOLERANCE,
             max_iterations: int = IK_MAX_ITERATIONS, damping: float = IK_DAMPING) -> IkResult:
    """Coordinates q near q0 that reach the targets, moving only the coordinates `dofs`
    (indices into q; hinge h is ROOT_DOF + h). `limits` (nh, 2) rad bounds the hinges.
    `damping` (m^2): of the damped least squares; a larger one keeps the step bounded when
    the targets are out of reach (more targets than free coordinates, a straight knee)."""
    q = q0.copy()
    cols = np.array(dofs)
    is_hinge = cols >= ROOT_DOF
    hinge_cols = cols[is_hinge]
    lo = limits[hinge_cols - ROOT_DOF, 0]
    hi = limits[hinge_cols - ROOT_DOF, 1]
    err = np.inf
    it = 0
    for it in range(max_iterations + 1):
        res, J = _rows(q, arrays, targets)
        err = float(np.max(np.abs(res)))
        if err < tol or it == max_iterations:
            break
        _ik_update(q, J, res, cols, is_hinge, lo, hi, damping)
    return IkResult(q, err, it)


@njit(cache=True)
def _ik_update(q, J, res, cols, is_hinge, lo, hi, damping):
    """One damped least-squares step of `solve_ik`, applied to q in place: the coordinates
    `cols` (hinges where `is_hinge`, bounded by lo, hi in their order) move by
    J^T (J J^T + damping I)^-1 res over the free columns. A hinge at a limit that the step
    would push further out is held there and the step recomputed without it (otherwise the
    clamp undoes part of every step and the iteration stalls: a straight knee at its stop)."""
    nc = cols.shape[0]
    m = res.shape[0]
    free = np.ones(nc, dtype=np.bool_)
    step = np.zeros(nc)
    for _ in range(int(is_hinge.sum()) + 1):
        idx = np.flatnonzero(free)
        Jd = np.empty((m, idx.shape[0]))
        for i in range(m):
            for j in range(idx.shape[0]):
                Jd[i, j] = J[i, cols[idx[j]]]
        A = matmul(Jd, Jd.T)
        for i in range(m):
            for j in range(m):
                A[i, j] += damping if i == j else 0.0  # (as + damping * I: -0.0 becomes 0.0)
        sub = tmatvec(Jd, solve(A, res))
        step = np.zeros(nc)
        for j in range(idx.shape[0]):
            step[idx[j]] = sub[j]
        stuck = False
        h = 0
        for j in range(nc):
            if not is_hinge[j]:
                continue
            qj = q[cols[j]]
            new = qj + step[j]
            out = (new < lo[h] and qj <= lo[h] + 1e-12) or (new > hi[h] and qj >= hi[h] - 1e-12)
            if out and free[j]:
                stuck = True
                free[j] = False
            h += 1
        if not stuck:
            break
    h = 0
    for j in range(nc):
        c = cols[j]
        q[c] += step[j]
        if is_hinge[j]:
            if q[c] < lo[h]:
                q[c] = lo[h]
            elif q[c] > hi[h]:
                q[c] = hi[h]
            h += 1
