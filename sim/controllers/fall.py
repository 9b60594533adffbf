"""The fall controller: what takes over once balance is lost."""

from __future__ import annotations

import numpy as np

from sim.character import ROOT_DOF, Character
from sim.controllers.base import Cmrt, Controller, Observation

FALL_STIFFNESS = 30.0  # N m / rad, the fall controller's low stiffness
FALL_KD_STABILITY = 0.5  # explicit PD stays stable for kd dt / I below ~1: keep a margin


class FallController(Controller):
    """Low-stiffness, critically damped joint PD holding the pose at hand-over."""

    def __init__(self, character: Character, dt: float):
        ch = character
        a_chi = ch.com0[1:] - ch.anchor0[1:]
        inertia_about_joint = ch.inertia[1:] + ch.mass[1:] * (a_chi**2).sum(axis=1)
        self.kp = FALL_STIFFNESS
        kd = 2.0 * np.sqrt(self.kp * inertia_about_joint)
        self.kd = np.minimum(kd, FALL_KD_STABILITY * inertia_about_joint / dt)
        self.target = np.zeros(ch.n_hinges)

    def engage(self, hinge_q: np.ndarray) -> None:
        self.target = hinge_q.copy()

    def torques(self, hinge_q: np.ndarray, hinge_qd: np.ndarray) -> np.ndarray:
        return self.kp * (self.target - hinge_q) - self.kd * hinge_qd

    # ---- the Controller protocol (it never hands over: `lost` stays None) -------------------
    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None:
        """Hold the pose of `observation` (the moment of hand-over); None holds the zero pose."""
        if observation is None:
            self.target = np.zeros_like(self.target)
        else:
            self.engage(observation.q[ROOT_DOF:])

    def act(self, observation: Observation, t: float) -> np.ndarray:
        return self.torques(observation.q[ROOT_DOF:], observation.qd[ROOT_DOF:])
