"""What a controller type is: its spec block (`ControllerConfig`) and how it is built.

The spec's `controller` field is a discriminated union on `type` over the registry
`sim.controllers.registry.CONTROLLER_TYPES`:

    controller: {type: momentum, k_l: 30}       # the momentum QP (the default) with overrides
    controller: {type: pd_world, k1: 100}       # (see sim.controllers.pd)

A block without `type` is refused (`sim.spec.format_error` says what to send); a spec without
the block has the momentum controller with its default gains.

Contract of a `ControllerConfig` (a pydantic model with a `type: Literal[...]` tag):
  * `check(spec, character)`: rules that need the rest of the spec or the character; raises
    ValueError whose message starts with the field's path (`controller.k1: ...`).
  * `build(context) -> Controller`: the run-time controller (the protocol of
    `sim.controllers.base`) for one rollout; `context` is a `ControllerContext`.
  * `schedules_gains`: whether the spec's `schedule` (gain schedules of the momentum gains)
    applies to this controller; a spec with a schedule and a controller that does not take
    one is rejected at parse time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from sim.specbase import StrictModel, count, quantity

if TYPE_CHECKING:
    from sim.character import Character
    from sim.controllers.base import Controller
    from sim.dynamics import ModelArrays
    from sim.trajectory import PoseTrajectory

#: Names accepted in momentum overrides and gain schedules (the fields of
#: sim.controllers.momentum.ControllerParams that a spec may set).
GAIN_NAMES: tuple[str, ...] = ("k_l", "d_l", "d_l_vertical", "k_t", "d_t", "b_l", "b_h", "b_t",
                               "b_p", "cop_box")
#: The type a `controller` block without `type` has.
DEFAULT_CONTROLLER = "momentum"

#: The range of a gain or weight override (0 is not a gain: a term is switched off by a
#: schedule's `set`); cop_box, in metres, is also bounded by the character's support.
_STIFFNESS = quantity(0.001, 1e4, "s^-2")
_DAMPING = quantity(0.001, 1e4, "s^-1")
_WEIGHT = quantity(0.001, 1e4, "(weight)")
#: The settings of the step controller a `momentum` block may set (only with `stepping: true`;
#: the fields of `sim.controllers.stepping.SteppingParams`, whose defaults apply when absent).
STEPPING_FIELDS: tuple[str, ...] = ("response_delay", "capture_margin", "step_duration",
                                    "clearance", "max_step_fraction", "max_steps")


@dataclass(frozen=True)
class ControllerContext:
    """What a controller is built from: the spec, its character and model arrays, the task's
    reference pose trajectory, the simulation step (s), the ground friction coefficient and
    the clip's initial (standing) generalised coordinates q."""

    spec: Any  # sim.spec.TaskSpec (not imported: the spec imports this module)
    character: Character
    arrays: ModelArrays
    trajectory: PoseTrajectory
    dt: float
    mu: float
    standing: np.ndarray


class ControllerConfig(StrictModel):
    """Base of every controller type's spec block; see the module docstring."""

    type: str
    schedules_gains: ClassVar[bool] = False

    def check(self, spec: Any, character: Character) -> None:
        return None

    def build(self, context: ControllerContext) -> Controller:
        raise NotImplementedError


class MomentumConfig(ControllerConfig):
    """`controller: {type: momentum, <gain>: value, ...}`: the momentum QP
    (sim.controllers.momentum) with the named gains and weights overriding ControllerParams'
    defaults. `stepping: true` adds the step controller (sim.controllers.stepping): feet
    planted while the capture point stays in the support, one step when it does not. Only with
    stepping, each absent one taking the step controller's default:
      * `response_delay` (s, 0 to 1, default 0; the stepping paper's 0.2 is an option): how
        long after the capture point leaves the support the step starts;
      * `capture_margin` (m, 0 to 0.3, default 0): how far beyond the toe or heel the capture
        point may go before a step is due;
      * `step_duration` (s, 0.1 to 1, default 0.3): the planned swing time;
      * `clearance` (m, 0.01 to 0.3, default 0.05): the swing foot's lift at mid-swing;
      * `max_step_fraction` (of the leg length, 0.1 to 1, default 0.7): the longest step,
        measured from the stance foot's sole centre;
      * `max_steps` (1 to 20, default 6): the steps a clip may take (the first and the
        follow-ups);
      * `feet_fixed` ({gain: value}): overrides gains in the feet-fixed phase before a step
        only; absent, the step controller's own default `{cop_box: 0.005, d_l: 20}` (300 N for
        0.1 s on the pelvis then needs no step); `{}` keeps the spec's gains there."""

    type: Literal["momentum"] = "momentum"
    stepping: bool = False
    k_l: _STIFFNESS | None = None
    d_l: _DAMPING | None = None
    d_l_vertical: _DAMPING | None = None
    k_t: _STIFFNESS | None = None
    d_t: _DAMPING | None = None
    b_l: _WEIGHT | None = None
    b_h: _WEIGHT | None = None
    b_t: _WEIGHT | None = None
    b_p: _WEIGHT | None = None
    cop_box: quantity(0.001, 1.0, "m") | None = None
    response_delay: quantity(0.0, 1.0, "s") | None = None
    capture_margin: quantity(0.0, 0.3, "m") | None = None
    step_duration: quantity(0.1, 1.0, "s") | None = None
    clearance: quantity(0.01, 0.3, "m") | None = None
    max_step_fraction: quantity(0.1, 1.0, "(of the leg length)") | None = None
    max_steps: count(1, 20, "steps") | None = None
    feet_fixed: dict[str, quantity(0.001, 1e4, "in the gain's unit")] | None = None

    schedules_gains: ClassVar[bool] = True

    @model_validator(mode="before")
    @classmethod
    def _known_names(cls, data: Any) -> Any:
        """An unknown key is an unknown gain (the legacy message, naming the gains)."""
        if isinstance(data, dict):
            for name in data:
                if name not in cls.model_fields:
                    raise ValueError(f"unknown gain {name!r}; gains are {', '.join(GAIN_NAMES)}")
        return data

    @model_validator(mode="after")
    def _delay_needs_stepping(self) -> MomentumConfig:
        for name in STEPPING_FIELDS:
            if getattr(self, name) is not None and not self.stepping:
                raise ValueError(f"{name}: applies only with stepping: true")
        if self.feet_fixed is not None:
            if not self.stepping:
                raise ValueError("feet_fixed: applies only with stepping: true")
            bad = sorted(set(self.feet_fixed) - set(GAIN_NAMES))
            if bad:
                raise ValueError(f"feet_fixed: unknown gain {bad[0]!r}; gains are "
                                 f"{', '.join(GAIN_NAMES)}")
        return self

    @model_serializer(mode="wrap")
    def _drop_unset_gains(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Dump only the overrides that are set (a default spec dumps `{type: momentum,
        stepping: false}`)."""
        return {k: v for k, v in handler(self).items() if v is not None}

    def overrides(self) -> dict[str, float]:
        """{gain name: value} of the gains this block sets."""
        return {k: v for k in GAIN_NAMES if (v := getattr(self, k)) is not None}

    def build(self, context: ControllerContext) -> Controller:
        from sim.controllers.momentum import ControllerParams, GainScheduler, MomentumController

        spec = context.spec
        params = ControllerParams().with_overrides(self.overrides())
        entries = []
        for s in spec.schedule:
            start, end = spec.schedule_window(s)
            entries.append((start, end, s.ramp, dict(s.scale), dict(s.set)))
        schedule = GainScheduler(params, entries)
        if self.stepping:
            from sim.controllers.stepping import SteppingController, SteppingParams

            kw: dict[str, Any] = {name: v for name in STEPPING_FIELDS
                                  if (v := getattr(self, name)) is not None}
            if self.feet_fixed is not None:  # {}: the spec's gains
                kw["feet_fixed_gains"] = tuple(sorted(self.feet_fixed.items()))
            step = SteppingParams(**kw)
            return SteppingController(context.character, schedule, context.trajectory,
                                      context.arrays, dt=context.dt, mu=context.mu, params=step)
        return MomentumController(context.character, schedule, context.trajectory,
                                  context.arrays, dt=context.dt, mu=context.mu)
