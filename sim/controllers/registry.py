"""The registry of controller types, resolved by the spec's `controller.type`.

Each entry is a `ControllerConfig` subclass (contract in `sim.controllers.config`); the spec's
`controller` field is the union of them, and every rollout builds its controller through
`build_controller` (the one factory). A new controller type is a config class plus one line
here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sim.controllers.config import (
    DEFAULT_CONTROLLER,
    ControllerConfig,
    ControllerContext,
    MomentumConfig,
)

if TYPE_CHECKING:
    from sim.controllers.base import Controller

CONTROLLER_TYPES: dict[str, type[ControllerConfig]] = {
    "momentum": MomentumConfig,
}


def build_controller(config: ControllerConfig, context: ControllerContext) -> Controller:
    """The run-time controller of a spec's `controller` block."""
    return config.build(context)


__all__ = ["CONTROLLER_TYPES", "DEFAULT_CONTROLLER", "ControllerConfig", "ControllerContext",
           "build_controller"]
