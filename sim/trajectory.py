"""Reference pose trajectories: the standing pose changed by timed motions (quintic easing) and
by dense tracks of frames (a clamped cubic spline through them)."""

from __future__ import annotations

from collections.abc import Sequence

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


class FrameTrack:
    """Offsets of some hinges (rad) sampled at a constant rate from `start` (s), interpolated by
    the clamped cubic spline through the frames: C2 between the first and the last frame, zero
    velocity at both ends. It holds its first frame before `start` and its last after the end,
    so that with the holds the offset is C1 everywhere (its acceleration steps at the two ends
    only)."""

    def __init__(self, start: float, interval: float, hinges: list[int], offsets: np.ndarray):
        y = np.asarray(offsets, dtype=float)
        if y.ndim != 2 or y.shape[0] < 2 or y.shape[1] != len(hinges) or interval <= 0.0:
            raise ValueError("a frame track needs >= 2 frames of one offset per hinge and a "
                             "positive interval")
        self.start = start
        self.interval = interval
        self.hinges = list(hinges)
        self.end = start + interval * (y.shape[0] - 1)
        self.first, self.last = y[0].copy(), y[-1].copy()
        # Per interval i, the offset at tau s into it is c0 + c1 tau + c2 tau^2 + c3 tau^3.
        h = interval
        m = clamped_slopes(y, h)
        dy = y[1:] - y[:-1]
        self.c0 = y[:-1].copy()
        self.c1 = m[:-1].copy()
        self.c2 = (3.0 * dy / h - 2.0 * m[:-1] - m[1:]) / h
        self.c3 = (m[:-1] + m[1:] - 2.0 * dy / h) / (h * h)
        self._zero = np.zeros(len(hinges))

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(offsets, rates, accelerations) of the track's hinges at t (s)."""
        if t <= self.start:
            return self.first, self._zero, self._zero
        if t >= self.end:
            return self.last, self._zero, self._zero
        i = min(int((t - self.start) / self.interval), self.c0.shape[0] - 1)
        tau = t - self.start - i * self.interval
        c1, c2, c3 = self.c1[i], self.c2[i], self.c3[i]
        return (self.c0[i] + tau * (c1 + tau * (c2 + tau * c3)),
                c1 + tau * (2.0 * c2 + 3.0 * tau * c3),
                2.0 * c2 + 6.0 * tau * c3)


def clamped_slopes(y: np.ndarray, h: float) -> np.ndarray:
    """Slopes at the knots (rows of `y`, spaced `h`) of the C2 cubic spline through them with
    zero slope at both ends: m[i-1] + 4 m[i] + m[i+1] = 3 (y[i+1] - y[i-1]) / h inside, solved
    by the Thomas algorithm (the system is diagonally dominant)."""
    n = y.shape[0]
    m = np.zeros_like(y)
    if n < 3:
        return m
    rhs = 3.0 * (y[2:] - y[:-2]) / h  # rows 1 .. n-2
    k = n - 2
    c = np.empty(k)
    d = np.empty_like(rhs)
    c[0] = 0.25
    d[0] = rhs[0] / 4.0
    for i in range(1, k):
        w = 4.0 - c[i - 1]
        c[i] = 1.0 / w
        d[i] = (rhs[i] - d[i - 1]) / w
    m[k] = d[k - 1]
    for i in range(k - 2, -1, -1):
        m[i + 1] = d[i] - c[i] * m[i + 2]
    return m


class PoseTrajectory:
    """Reference hinge trajectory: the standing pose, changed by motions in time order, plus
    the offsets of any frame tracks.

    Each motion (start s, duration T, offsets in radians relative to the standing pose for some
    joints) eases the named joints from their previous target to the new one; each track adds
    its offsets (and their rates and accelerations) to its hinges.
    """

    def __init__(self, standing: np.ndarray, motions: list[MotionDef],
                 tracks: Sequence[FrameTrack] = ()):
        self.standing = standing.copy()
        self.tracks = tuple(tracks)
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
        for track in self.tracks:
            v, vd, vdd = track(t)
            q[track.hinges] += v
            qd[track.hinges] += vd
            qdd[track.hinges] += vdd
        return q, qd, qdd


