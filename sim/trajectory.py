"""Reference pose trajectories: the standing pose changed by timed motions (quintic easing)."""

from __future__ import annotations

import numpy as np

#: A motion: (start s, duration s, {hinge index: offset from the standing pose, rad}).
MotionDef = tuple[float, float, dict[int, float]]


def ease(u: float) -> tuple[float, float, float]:
    """Quintic ease-in-ease-out s(u) on [0, 1] and its first two derivatives in u (C2)."""
    if u <= 0.0:
        return 0.0, 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0, 0.0
    u2 = u * u
    return (u2 * u * (10.0 - 15.0 * u + 6.0 * u2),
            30.0 * u2 * (1.0 - 2.0 * u + u2),
            60.0 * u * (1.0 - 3.0 * u + 2.0 * u2))


class PoseTrajectory:
    """Reference hinge trajectory: the standing pose, changed by motions in time order.

    Each motion (start s, duration T, offsets in radians relative to the standing pose for some
    joints) eases the named joints from their previous target to the new one.
    """

    def __init__(self, standing: np.ndarray, motions: list[MotionDef]):
        self.standing = standing.copy()
        self.segments: list[tuple[float, float, int, float, float]] = []  # start, T, j, from, to
        current = standing.copy()
        for start, dur, targets in sorted(motions, key=lambda m: m[0]):
            for j, off in targets.items():
                goal = standing[j] + off
                self.segments.append((start, dur, j, current[j], goal))
                current[j] = goal

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q = self.standing.copy()
        qd = np.zeros(q.shape[0])  # zeros_like's values, without its Python wrapper
        qdd = np.zeros(q.shape[0])
        for start, dur, j, a, b in self.segments:
            if t < start:
                continue
            s, ds, dds = ease((t - start) / dur)
            q[j] = a + (b - a) * s
            qd[j] = (b - a) * ds / dur
            qdd[j] = (b - a) * dds / (dur * dur)
        return q, qd, qdd


