"""The controller protocol and what every controller observes.

Contract of a `Controller` (every controller derives from the base class below, which declares
everything the rollout may ask of one and its default; the rollout asks nothing else):
  * `reset(observation=None, reference=None)` starts a run: `observation` is the state at the
    moment the controller takes over (None at the clip's start), `reference` the CMRT for
    controllers that track one (a callable t -> horizontal [, vertical] CM displacement in m).
  * `act(observation, t) -> torques` is called once per simulation step (t in s from the clip
    start) and returns the hinge torques (N m, +t on the child, hinge order of the character);
    the physics clamps them to the character's torque limits.
  * `lost` is None while the controller holds balance, else a short reason: the rollout then
    hands over to the fall controller. A controller never steps the world or reads ODE.
  * `stance`: the indices (into `character.feet`) of the feet the controller treats as
    planted for the next step, None (the default) for every foot. The rollout builds the
    observation's `Js`, `points`, `sole_x` and `support` from those feet only
    (`stance_terms`), so a swing foot's constraint rows are dropped.
  * `c_ref` is the CM reference (x in m, vertical displacement in m) of the last `act`, what
    the recording shows beside the CM (a controller without a CM target of its own reports
    the support centre plus the CMRT displacement it follows).
  * held steps (optional, default off): `held_torque_step()` True says that this step's `act`
    would only hold the accelerations `qdd` (rad/s^2, per coordinate) and share the support
    wrench by least norm over every foot with friction coefficient `mu`; the rollout then
    computes those torques in one compiled call with the model terms
    (`sim.dynamics.step_model_held`) and calls `held_act(code, top)` instead of `act`, with
    the same torques and state, bit for bit.
  * Balance controllers are built from the spec's `controller` block by one factory,
    `sim.controllers.registry.build_controller` (contract in `sim.controllers.config`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

Cmrt = Callable[[float], Any]


@dataclass(slots=True)
class Observation:
    """The character's state and model terms at one step (see sim.dynamics.step_model).

    The rollout writes every step's values into the same arrays (`Physics.read_state`,
    `sim.dynamics.step_model_packed`): a controller that keeps one past its step copies it."""

    q: np.ndarray  # generalised coordinates [root x, y, angle, hinges]
    qd: np.ndarray
    M: np.ndarray  # mass matrix
    h: np.ndarray  # gravity + Coriolis
    c: np.ndarray  # (2,) centre of mass
    cd: np.ndarray  # (2,) its velocity
    A_L: np.ndarray  # linear momentum rows
    A_H: np.ndarray  # angular momentum row about the CoM
    Js: np.ndarray  # stance-feet constraint Jacobian (3 rows per stance foot)
    points: np.ndarray  # (2 k, 2) heel/toe points of the stance feet
    sole_x: np.ndarray  # sole centres x of the stance feet
    support: tuple[float, float]  # (back edge x, front edge x) of the stance feet's support
    #: Indices into `character.feet` of the stance feet (those the rows above describe);
    #: None: every foot (double support, the feet-fixed default).
    stance: tuple[int, ...] | None = None


def stance_terms(Js: np.ndarray, points: np.ndarray, sole_x: np.ndarray,
                 support: tuple[float, float], stance: tuple[int, ...] | None,
                 n_feet: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float]]:
    """(Js, points, sole_x, support) of the stance feet only, from the every-foot terms of
    `sim.dynamics.step_model` (3 rows of Js, 2 points (heel, toe) per foot). With every foot in
    stance (or None) the arrays are returned as they are, so double support is unchanged bit
    for bit. The support spans the stance feet's heels and toes: both feet down at different
    x give one interval from the rear heel to the front toe."""
    if stance is None or len(stance) == n_feet:
        return Js, points, sole_x, support
    if not stance:
        raise ValueError("a stance needs at least one foot")
    rows = [3 * f + r for f in stance for r in range(3)]
    pts = points[[2 * f + r for f in stance for r in range(2)]]
    lo = min(float(points[2 * f, 0]) for f in stance)
    hi = max(float(points[2 * f + 1, 0]) for f in stance)
    return Js[rows], pts, sole_x[list(stance)], (lo, hi)


class Controller:
    """What the rollout may ask of a controller (module doc), with the defaults of a controller
    that plants every foot and has no held steps."""

    #: None while balance holds, else why it was lost.
    lost: str | None = None
    #: m: the CM reference (x, vertical displacement) of the last `act`.
    c_ref: tuple[float, float] = (0.0, 0.0)
    #: Indices into `character.feet` of the feet planted for the next step; None: every foot.
    stance: tuple[int, ...] | None = None
    #: Friction coefficient of a held step's wrench check (read only when held steps are on).
    mu: float = 0.0
    #: rad/s^2 (m/s^2 for the root's x, y): the accelerations a held step holds.
    qdd: np.ndarray

    @property
    def foot_steps(self) -> int | None:
        """Steps taken since `reset` by a controller that steps; None for one that never
        does (what `cmrt sweep` reports per cell)."""
        return None

    def reset(self, observation: Observation | None = None,
              reference: Cmrt | None = None) -> None:
        """Start a run (module doc)."""
        raise NotImplementedError

    def act(self, observation: Observation, t: float) -> np.ndarray:
        """This step's hinge torques (N m)."""
        raise NotImplementedError

    def held_torque_step(self) -> bool:
        """Whether the next step is a held step (module doc); never, by default."""
        return False

    def held_act(self, code: int, top: float) -> None:
        """What `act` does after its inverse dynamics on a held step, given the wrench code and
        the highest stance heel or toe (m) that `sim.dynamics.step_model_held` found."""
        raise NotImplementedError(f"{type(self).__name__} has no held steps")
