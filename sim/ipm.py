"""The inverted pendulum model (IPM) of a step: when to step, where to, and the CM's path.

The whole body is reduced to a point mass (the CM) on a massless stiff leg pivoting on the
ground at the support foot's centre of pressure (the paper's model before foot contact):

    theta'' = (g / l) sin(theta),   x = p + l sin(theta),  y = l cos(theta)

theta is the lean from the vertical (positive forward, +x), l = |CM - pivot| is held. It is
integrated with fourth-order Runge-Kutta at IPM_DT. `capture_point` is the linearised model's
(constant height) capture point xi = x + xd sqrt(y / g): the point where the CoP must be for
the CM to come to rest over it. Feet-fixed balance can hold only while xi stays (nearly) inside
the support; a step puts the new foot under the capture point predicted at touch-down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.dynamics import GRAVITY

IPM_DT = 0.001  # s, integration step of the pendulum


def capture_point(c: np.ndarray, cd: np.ndarray, ground: float = 0.0) -> float:
    """x (m) of the linear inverted pendulum's capture point of the CM (c, cd)."""
    return float(c[0] + cd[0] * math.sqrt(max(float(c[1]) - ground, 1e-6) / GRAVITY))


def step_direction(xi: float, support: tuple[float, float], margin: float) -> int:
    """+1 (step forward) when the capture point xi is more than `margin` (m) ahead of the
    support's front edge, -1 (backward) when as far behind its back edge, else 0 (the feet can
    stay planted)."""
    lo, hi = support
    if xi > hi + margin:
        return 1
    if xi < lo - margin:
        return -1
    return 0


@dataclass(frozen=True)
class PendulumPath:
    """The IPM's CM path from a start time: samples every IPM_DT (times relative to t0).
    `push` (m/s^2) is a constant horizontal acceleration of the mass from outside (an
    estimated push; 0: the plain pendulum)."""

    t0: float
    pivot: float
    length: float
    theta: np.ndarray
    theta_d: np.ndarray
    push: float = 0.0

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(CM position, velocity, acceleration), each (2,), at time t (clamped to the path)."""
        u = (t - self.t0) / IPM_DT
        k = int(min(max(math.floor(u), 0), len(self.theta) - 2))
        f = min(max(u - k, 0.0), 1.0)
        th = (1 - f) * self.theta[k] + f * self.theta[k + 1]
        w = (1 - f) * self.theta_d[k] + f * self.theta_d[k + 1]
        lg = self.length
        s, co = math.sin(th), math.cos(th)
        wd = GRAVITY / lg * s + (self.push * co / lg if self.push else 0.0)
        pos = np.array([self.pivot + lg * s, lg * co])
        vel = np.array([lg * co * w, -lg * s * w])
        acc = np.array([lg * (co * wd - s * w * w), -lg * (s * wd + co * w * w)])
        return pos, vel, acc

    @property
    def duration(self) -> float:
        return (len(self.theta) - 1) * IPM_DT


def pendulum_path(c: np.ndarray, cd: np.ndarray, pivot: float, duration: float,
                  t0: float = 0.0, push: float = 0.0) -> PendulumPath:
    """Integrate the IPM from the CM state (c, cd) about the ground point x = pivot for
    `duration` s. The leg length is |c - pivot|; the initial lean rate is the CM velocity's
    component across the leg divided by it. `push` (m/s^2): a constant horizontal
    acceleration from outside, theta'' = (g sin theta + push cos theta) / l."""
    dx, dy = float(c[0] - pivot), float(c[1])
    lg = math.hypot(dx, dy)
    th = math.atan2(dx, dy)
    w = (float(cd[0]) * math.cos(th) - float(cd[1]) * math.sin(th)) / lg
    n = max(int(math.ceil(duration / IPM_DT)), 1)
    thetas, rates = _integrate(th, w, GRAVITY / lg, push / lg, IPM_DT, n)
    return PendulumPath(t0, pivot, lg, thetas, rates, push)


@njit(cache=True)
def _pendulum_accel(x, k, kp):
    """theta'' at lean x: k sin x (+ kp cos x under a push)."""
    return k * math.sin(x) + kp * math.cos(x) if kp != 0.0 else k * math.sin(x)


@njit(cache=True)
def _integrate(th, w, k, kp, h, n):
    """n RK4 steps of h s of theta'' = k sin theta + kp cos theta from (th, w): the leans and
    lean rates (n + 1,) each (compiled: a re-plan integrates the rest of the swing at every
    swing solve)."""
    thetas = np.empty(n + 1)
    rates = np.empty(n + 1)
    thetas[0], rates[0] = th, w
    for i in range(n):
        a1 = _pendulum_accel(th, k, kp)
        a2 = _pendulum_accel(th + 0.5 * h * w, k, kp)
        a3 = _pendulum_accel(th + 0.5 * h * (w + 0.5 * h * a1), k, kp)
        a4 = _pendulum_accel(th + h * (w + 0.5 * h * a2), k, kp)
        th, w = (th + h * (w + h * (a1 + a2 + a3) / 6.0),
                 w + h * (a1 + 2.0 * a2 + 2.0 * a3 + a4) / 6.0)
        thetas[i + 1], rates[i + 1] = th, w
    return thetas, rates


@dataclass(frozen=True)
class StepPlan:
    """A planned step: the CM's IPM path over the swing, and the swing foot's sole-centre
    path (lift-off at `start`, touch-down at `land`, both (x, y) in m) over `duration` s."""

    t0: float
    duration: float
    direction: int
    path: PendulumPath
    start: tuple[float, float]
    land: tuple[float, float]
    clearance: float
    capture_at_land: float

    def foot(self, t: float) -> tuple[float, float]:
        """Planned sole-centre position of the swing foot at t: a quintic ease along x and a
        quartic lift 16 h s^2 (1 - s)^2 of `clearance` h over the swing (level at lift-off and
        touch-down, so the foot meets the ground slowly), aimed slightly below the ground at the end
        so the foot meets it (held there after the planned touch-down)."""
        from sim.trajectory import ease  # (local: keeps this module's imports light)
        s = min(max((t - self.t0) / self.duration, 0.0), 1.0)
        e = ease(s)[0]
        x = self.start[0] + (self.land[0] - self.start[0]) * e
        y = (self.start[1] + (self.land[1] - self.start[1]) * s
             + 16.0 * self.clearance * (s * (1.0 - s)) ** 2)
        return x, y


def plan_step(t0: float, c: np.ndarray, cd: np.ndarray, pivot: float,
              swing_start: tuple[float, float], direction: int, duration: float,
              clearance: float, max_step: float, land_depth: float = 0.01,
              reach_from: float | None = None,
              push: float = 0.0) -> StepPlan:
    """Plan a step from the state (c, cd) at t0 with the CoP held at `pivot`: the IPM gives the
    CM at touch-down (t0 + duration) and its capture point there; the swing foot's sole centre
    lands at that point, so the capture point lies over the new foot, at most `max_step` (m)
    from `reach_from` (x of the stance foot's sole centre: the leg's reach; None: from where
    the swing foot started) and never behind where it started. `land_depth` (m): the foot is
    aimed this far below the ground so that it makes contact. `push` (m/s^2): an estimated
    horizontal acceleration from outside, held over the swing (`pendulum_path`)."""
    path = pendulum_path(c, cd, pivot, duration, t0, push)
    pos, vel, _acc = path.state(t0 + duration)
    xi = capture_point(pos, vel)
    x_land = _landing(xi, swing_start[0], direction, max_step, reach_from)
    return StepPlan(t0, duration, direction, path, (float(swing_start[0]), float(swing_start[1])),
                    (float(x_land), -land_depth), clearance, xi)


def _landing(x_goal: float, start: float, direction: int, max_step: float,
             reach_from: float | None) -> float:
    """x_goal limited to at most max_step beyond `reach_from` (or `start` when None) along
    `direction`, and never behind `start`."""
    base = start if reach_from is None else reach_from
    x = base + direction * min(direction * (x_goal - base), max_step)
    return start + direction * max(direction * (x - start), 0.0)


def replan_step(plan: StepPlan, t: float, c: np.ndarray, cd: np.ndarray, max_step: float,
                reach_from: float | None = None, push: float = 0.0) -> StepPlan:
    """The same step (lift-off, touch-down time, pivot) re-planned from the CM state at t: the
    IPM from (c, cd) over what is left of the swing, and the landing under its new capture point.
    A push still acting when the step started moves the capture point on; re-planning follows it
    (the controller does not know the force; `push`, m/s^2, is its estimate from the measured
    CM, held to touch-down). `max_step`, `reach_from`: as in `plan_step`."""
    t_land = plan.t0 + plan.duration
    path = pendulum_path(c, cd, plan.path.pivot, max(t_land - t, IPM_DT), t, push)
    pos, vel, _acc = path.state(t_land)
    xi = capture_point(pos, vel)
    d = plan.direction
    x_land = _landing(xi, plan.start[0], d, max_step, reach_from)
    return StepPlan(plan.t0, plan.duration, d, path, plan.start,
                    (float(x_land), plan.land[1]), plan.clearance, xi)
