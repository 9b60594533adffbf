"""Recording beside the rollout: the 1 kHz traces and the replay frames.

`Recorder(n_steps, physics)`: `trace(...)` once per step (CP, support centre, CP error, CM, CM
reference: `sim.clip_result.Traces`, and the joint state q the step started from:
`sim.clip_result.States`), `frame(...)` at the start of every FRAME_EVERY-th step
(poses of every body and prop read from ODE, CM, CM reference, CP, support edges:
`sim.clip_result.Frames`). Nothing here changes the simulation.
"""

from __future__ import annotations

import math

import numpy as np

from sim.clip_result import Frames, States, Traces
from sim.physics import DT, Physics

FRAME_RATE = 100.0  # Hz, replay frames
FRAME_EVERY = max(1, int(round(1.0 / (FRAME_RATE * DT))))


class Recorder:
    def __init__(self, n_steps: int, physics: Physics):
        self.physics = physics
        self.tr = {k: np.full(n_steps, np.nan) for k in ("t", "cp", "support", "error", "normal")}
        self.cm = np.full((n_steps, 2), np.nan)
        self.ref = np.full((n_steps, 2), np.nan)
        self.q = np.full((n_steps, len(physics.q)), np.nan)
        self.frames = Frames(rate=1.0 / (FRAME_EVERY * DT), names=physics.pose_names(), t=[],
                             poses=[], cm=[], cm_ref=[], cp=[], support=[])
        self._last_cp = math.nan

    def trace(self, k: int, t: float, cp: float, s: float, e: float, c: np.ndarray,
              c_ref: tuple[float, float], normal: float) -> None:
        """Step k, ending at time t (s): measured CP (NaN without contact), support centre,
        CP error, CM (x, y), CM reference (x, dy), the feet's total normal force (N)."""
        tr = self.tr
        tr["normal"][k] = normal
        tr["t"][k] = t
        tr["cp"][k] = cp
        tr["support"][k] = s
        tr["error"][k] = e
        self.cm[k] = c
        self.ref[k] = (c_ref[0], c[1] + c_ref[1])
        # physics.q still holds the state read when step k began (read_state runs only when
        # a step is observed): the state at t - DT, the one the CM c was computed from.
        self.q[k] = self.physics.q
        self._last_cp = cp

    def frame(self, t: float, c: np.ndarray, c_ref: tuple[float, float],
              support: tuple[float, float]) -> None:
        """A replay frame of the state at time t (before that step acts)."""
        f = self.frames
        f.t.append(t)
        f.poses.append(self.physics.poses())
        f.cm.append((float(c[0]), float(c[1])))
        f.cm_ref.append((float(c_ref[0]), float(c[1] + c_ref[1])))
        f.cp.append(float(self._last_cp))
        f.support.append((float(support[0]), float(support[1])))

    def result(self, n: int) -> tuple[Traces, Frames, States]:
        tr = self.tr
        traces = Traces(t=tr["t"][:n], cp=tr["cp"][:n], support=tr["support"][:n],
                        cm=self.cm[:n], cm_ref=self.ref[:n], error=tr["error"][:n],
                        normal=tr["normal"][:n])
        states = States(t=np.arange(n) * DT, q=self.q[:n])
        return traces, self.frames, states
