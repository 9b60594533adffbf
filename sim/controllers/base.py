"""The controller protocol and what every controller observes.

Contract of a `Controller`:
  * `reset(observation=None, reference=None)` starts a run: `observation` is the state at the
    moment the controller takes over (None at the clip's start), `reference` the CMRT for
    controllers that track one (a callable t -> horizontal [, vertical] CM displacement in m).
  * `act(observation, t) -> torques` is called once per simulation step (t in s from the clip
    start) and returns the hinge torques (N m, +t on the child, hinge order of the character);
    the physics clamps them to the character's torque limits.
  * `lost` is None while the controller holds balance, else a short reason: the rollout then
    hands over to the fall controller. A controller never steps the world or reads ODE.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

Cmrt = Callable[[float], Any]


@dataclass(slots=True)
class Observation:
    """The character's state and model terms at one step (see sim.dynamics.step_model).

    The rollout writes every step's values into the same arrays (`Physics.read_state`,
    `sim.dynamics.step_model_into`): a controller that keeps one past its step copies it."""

    q: np.ndarray  # generalised coordinates [root x, y, angle, hinges]
    qd: np.ndarray
    M: np.ndarray  # mass matrix
    h: np.ndarray  # gravity + Coriolis
    c: np.ndarray  # (2,) centre of mass
    cd: np.ndarray  # (2,) its velocity
    A_L: np.ndarray  # linear momentum rows
    A_H: np.ndarray  # angular momentum row about the CoM
    Js: np.ndarray  # stance-feet constraint Jacobian
    points: np.ndarray  # (k, 2) heel/toe points of the feet
    sole_x: np.ndarray  # sole centres x
    support: tuple[float, float]  # (back edge x, front edge x) of the support


class Controller(Protocol):
    lost: str | None

    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None: ...

    def act(self, observation: Observation, t: float) -> np.ndarray: ...
