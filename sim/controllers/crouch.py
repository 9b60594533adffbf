"""The vertical part of a CMRT as a posture: the legs bend (or straighten) so that the reference
posture's CM is `dy` m lower (higher) than the task's own reference posture's.

Why a posture (docs/physics.md, "The vertical CMRT"): the momentum QP tracks every hinge toward
the task's reference posture, and a lower CM needs the knees and hips to bend away from it. A
vertical CM target in the linear-momentum objective alone hardly moves the CM against the
tracking term (measured on the 180 kg character file in quiet stance: -10 / -20 cm asked, 1.6 /
3.6 mm reached with a force k_l m dy, 2.0 / 4.7 mm with a spring about the standing height),
so a displacement that the tracking term contradicts is not followed. The
horizontal CMRT is followed because it costs only the lightly weighted ankles and the free root
angle; lowering the CM costs the legs' heavily weighted hinges. So here the reference posture
itself carries the vertical displacement, as the PD servos carry the horizontal one through a
lean (docs/physics.md, "How a CMRT enters a PD servo"), and tracking and momentum agree.

The crouch of a leg: the root (and everything above it) moves straight down by h, keeping its
world angle; each foot stays where it is, flat; each leg's thigh and shank follow from the
two-link triangle between its hip and ankle anchors, the knee bending on the side it already
bends to. h is found so that the posture's CM height changes by dy (secant on the forward
kinematics). A leg is the hinge chain between the root and a foot (`sim.ik.leg_hinges`); the
crouch needs it to be three hinges (hip, knee, the foot's own), nothing names a joint. A crouch
that would bring a leg hinge within LIMIT_MARGIN of its limit (or straighten a leg past its
reach) stops there: the displacement is followed as far as the legs allow.
"""

from __future__ import annotations

import math

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.dynamics import ModelArrays, forward_kinematics
from sim.ik import leg_hinges
from sim.linalg import dot

#: rad: a crouch stops this far inside a leg hinge's limit (ODE's joint stops are hard).
LIMIT_MARGIN = math.radians(2.0)
#: m: the reached CM height is within this of the target (secant on h).
HEIGHT_TOLERANCE = 1e-9
MAX_ITERATIONS = 30
#: s, the half step of the central differences that give the crouch's rates.
RATE_STEP = 0.01


class Crouch:
    """Leg-hinge offsets that lower the reference posture's CM by dy (module docstring)."""

    def __init__(self, character: Character, arrays: ModelArrays):
        self.character = character
        self.arrays = arrays
        self.legs = [leg_hinges(character, int(f)) for f in character.feet]
        bad = [character.body_names[int(f)] for f, leg in zip(character.feet, self.legs,
                                                               strict=True) if len(leg) != 3]
        if bad:
            raise ValueError(f"cmrt.vertical: the crouch needs legs of three hinges (hip, knee, "
                             f"foot) between the root and each foot; not so for {bad}")
        self.hinges = np.array(sorted({j for leg in self.legs for j in leg}))
        self.lo = character.limits[self.hinges, 0] + LIMIT_MARGIN
        self.hi = character.limits[self.hinges, 1] - LIMIT_MARGIN
        a = arrays
        # Zero-pose thigh and shank vectors (hip -> knee, knee -> ankle anchors), per leg.
        self.segments = []
        for leg in self.legs:
            thigh, shank, foot = (j + 1 for j in leg)  # hinge j moves body j + 1
            u1 = character.anchor0[shank] - character.anchor0[thigh]
            u2 = character.anchor0[foot] - character.anchor0[shank]
            self.segments.append((thigh, shank, foot, float(np.hypot(*u1)),
                                  float(np.hypot(*u2)), math.atan2(u1[1], u1[0]),
                                  math.atan2(u2[1], u2[0])))
        self.mass = a.mass
        self.total = float(a.mass.sum())
        self._h = 0.0  # the last solution's drop, the next solve's first guess

    def _pose(self, q_r: np.ndarray) -> np.ndarray:
        """Full coordinates of the reference hinges with the first foot flat."""
        q = np.zeros(self.character.ndof)
        q[2] = -sum(q_r[j] for j in self.legs[0])
        q[ROOT_DOF:] = q_r
        return q

    def _crouched(self, q: np.ndarray, o: np.ndarray, alpha: np.ndarray,
                  h: float) -> np.ndarray | None:
        """q with the root down by h and the legs solved; None when a leg cannot reach."""
        out = q.copy()
        out[1] -= h
        phi = q[2]
        for leg, (thigh, shank, foot, l1, l2, b1, b2) in zip(self.legs, self.segments,
                                                            strict=True):
            hip = o[thigh] - np.array([0.0, h])
            ankle = o[foot]
            dx, dy = ankle[0] - hip[0], ankle[1] - hip[1]
            d = math.hypot(dx, dy)
            if d >= l1 + l2 or d <= abs(l1 - l2):
                return None
            gamma = math.acos(max(-1.0, min(1.0, (l1 * l1 + d * d - l2 * l2) / (2 * l1 * d))))
            # The knee stays on the side of the hip-ankle line it is on in the reference.
            kx, ky = o[shank][0] - o[thigh][0], o[shank][1] - o[thigh][1]
            side = 1.0 if (dx * ky - dy * kx) >= 0.0 else -1.0
            base = math.atan2(dy, dx)
            thigh_dir = base + side * gamma
            knee = (hip[0] + l1 * math.cos(thigh_dir), hip[1] + l1 * math.sin(thigh_dir))
            shank_dir = math.atan2(ankle[1] - knee[1], ankle[0] - knee[0])
            a_thigh, a_shank = thigh_dir - b1, shank_dir - b2
            out[ROOT_DOF + leg[0]] = a_thigh - phi
            out[ROOT_DOF + leg[1]] = a_shank - a_thigh
            out[ROOT_DOF + leg[2]] = alpha[foot] - a_shank
        return out

    def _height(self, q: np.ndarray) -> float:
        _, p, _ = forward_kinematics(q, self.arrays.parent, self.arrays.a_par, self.arrays.a_chi)
        return dot(self.mass, p[:, 1]) / self.total

    def _feasible(self, q: np.ndarray | None) -> bool:
        if q is None:
            return False
        hq = q[ROOT_DOF + self.hinges]
        return bool(np.all(hq >= self.lo) and np.all(hq <= self.hi))

    def offsets(self, q_r: np.ndarray, dy: float) -> np.ndarray:
        """Offsets (rad, per hinge; zero but on the legs) that change the CM height of the
        reference posture q_r by dy (m, negative: lower), or as far as the legs allow."""
        out = np.zeros_like(q_r)
        if dy == 0.0:
            return out
        q = self._pose(q_r)
        alpha, _, o = forward_kinematics(q, self.arrays.parent, self.arrays.a_par,
                                         self.arrays.a_chi)
        y0 = self._height(q)

        def miss(h: float) -> float | None:
            qc = self._crouched(q, o, alpha, h)
            return None if not self._feasible(qc) else self._height(qc) - y0 - dy

        # Secant from the last drop (warm start) and a first-order guess.
        h0, h1 = 0.0, self._h if self._h * dy < 0.0 else -dy
        f0 = -dy
        f1 = miss(h1)
        if f1 is None:
            h1 = self._limit(miss, h0, h1)
            f1 = miss(h1)
        for _ in range(MAX_ITERATIONS):
            if f1 is None or abs(f1) < HEIGHT_TOLERANCE or f1 == f0:
                break
            h2 = h1 - f1 * (h1 - h0) / (f1 - f0)
            f2 = miss(h2)
            if f2 is None:  # beyond the legs' range: the crouch stops at its edge
                h1 = self._limit(miss, h1, h2)
                break
            h0, f0, h1, f1 = h1, f1, h2, f2
        self._h = h1
        qc = self._crouched(q, o, alpha, h1)
        if qc is None:
            return out
        out[self.hinges] = qc[ROOT_DOF + self.hinges] - q_r[self.hinges]
        return out

    @staticmethod
    def _limit(miss, good: float, bad: float) -> float:
        """The feasible edge between drop `good` (feasible) and `bad` (not), by bisection."""
        for _ in range(40):
            mid = 0.5 * (good + bad)
            if miss(mid) is None:
                bad = mid
            else:
                good = mid
        return good
